/**
 * @file test_nvm_page.c
 * @brief The boards' parameter block in one flash page
 *        (firmware_c/boards/_common/nvm_page.c) on a flash model written here:
 *        erase sets every byte to 0xFF, a program operation can only clear
 *        bits of an erased unit, and power can be lost after any number of
 *        bytes of any operation.
 *
 * Checked: a block written whole reads back equal; erase reads as empty; a
 * write torn after every possible byte of its erase and program operations
 * boots the drive application (fw_app_attach_nvm) on its defaults (state
 * EMPTY or BAD_CRC), never on a mix; a failing medium is an error; a block
 * larger than the page is refused without erasing the stored one.
 */
#include <string.h>

#include "../../firmware_c/boards/_common/nvm_page.c"
#include "../../firmware_c/port/blank/fw_port_blank.c"
#include "pmlsm/fw_app.h"
#include "tinytest.h"

#define PAGE 2048u
#define UNIT 8u

typedef struct {
  uint8_t mem[PAGE];
  long budget;    /* bytes the medium still changes before power is lost (-1: no limit) */
  int dead;       /* power lost: nothing changes any more */
  int fail;       /* the medium reports an error */
  int bad_prog;   /* programs that were not on erased units (must stay 0) */
  int erases, programs;
} flash_t;

static int spend(flash_t *f) {
  if (f->dead) return 0;
  if (f->budget == 0) {
    f->dead = 1;
    return 0;
  }
  if (f->budget > 0) f->budget--;
  return 1;
}

static bool f_erase(void *ctx) {
  flash_t *f = (flash_t *)ctx;
  f->erases++;
  if (f->fail) return false;
  for (uint32_t i = 0; i < PAGE; i++) {
    if (!spend(f)) return true; /* the caller never learns: power is gone */
    f->mem[i] = 0xFF;
  }
  return true;
}

static bool f_program(void *ctx, uint32_t off, const uint8_t *d, uint32_t len) {
  flash_t *f = (flash_t *)ctx;
  f->programs++;
  if (f->fail) return false;
  if (off % UNIT != 0u || len % UNIT != 0u || off + len > PAGE) return false;
  for (uint32_t i = 0; i < len; i++) {
    if (f->mem[off + i] != 0xFF && !f->dead) f->bad_prog++;
    if (!spend(f)) return true;
    f->mem[off + i] &= d[i];
  }
  return true;
}

static const uint8_t *f_view(void *ctx) { return ((flash_t *)ctx)->mem; }

static flash_t g_flash;
static const nvm_page_t PAGEDEV = {&g_flash, PAGE, UNIT, f_erase, f_program, f_view};

/* the application's port functions on the page */
static fw_nvm_status_t app_read(fw_port_t *p, uint8_t *buf, size_t cap, size_t *len) {
  (void)p;
  return nvm_page_read(&PAGEDEV, buf, cap, len);
}
static fw_nvm_status_t app_write(fw_port_t *p, const uint8_t *d, size_t len) {
  (void)p;
  return nvm_page_write(&PAGEDEV, d, len);
}
static const fw_app_nvm_t NVM = {NULL, app_read, app_write};

static fw_app_t g_app, g_app2;

static void test_roundtrip_and_erase(void) {
  memset(&g_flash, 0xFF, sizeof g_flash.mem);
  g_flash.budget = -1;
  uint8_t buf[PAGE], out[PAGE];
  size_t len = 99u;
  TT_CHECK(nvm_page_read(&PAGEDEV, out, sizeof out, &len) == FW_NVM_EMPTY && len == 0u);
  for (size_t n = 1u; n <= nvm_page_capacity(&PAGEDEV); n += 37u) {
    for (size_t i = 0; i < n; i++) buf[i] = (uint8_t)(i * 7u + n);
    TT_CHECK(nvm_page_write(&PAGEDEV, buf, n) == FW_NVM_OK);
    TT_CHECK(nvm_page_read(&PAGEDEV, out, sizeof out, &len) == FW_NVM_OK);
    TT_CHECK(len == n && memcmp(out, buf, n) == 0);
  }
  TT_CHECK(g_flash.bad_prog == 0);
  TT_CHECK(nvm_page_write(&PAGEDEV, NULL, 0u) == FW_NVM_OK);
  TT_CHECK(nvm_page_read(&PAGEDEV, out, sizeof out, &len) == FW_NVM_EMPTY);
  /* too large: refused before anything is erased */
  TT_CHECK(nvm_page_write(&PAGEDEV, buf, 100u) == FW_NVM_OK);
  int e0 = g_flash.erases;
  TT_CHECK(nvm_page_write(&PAGEDEV, buf, PAGE) == FW_NVM_ERROR);
  TT_CHECK(g_flash.erases == e0);
  TT_CHECK(nvm_page_read(&PAGEDEV, out, sizeof out, &len) == FW_NVM_OK && len == 100u);
  /* a caller's buffer too small, a failing medium */
  TT_CHECK(nvm_page_read(&PAGEDEV, out, 50u, &len) == FW_NVM_ERROR);
  g_flash.fail = 1;
  TT_CHECK(nvm_page_write(&PAGEDEV, buf, 10u) == FW_NVM_ERROR);
  g_flash.fail = 0;
}

/* The application saves through the page; the write is torn after every byte
 * the medium changes; a fresh application boots from what is left: its own
 * defaults (EMPTY or BAD_CRC), or - only when the write completed - the block. */
static void test_torn_writes_boot_on_defaults(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  memset(&g_flash, 0xFF, sizeof g_flash.mem);
  g_flash.budget = -1;
  g_flash.dead = 0;
  TT_CHECK(fw_app_init(&g_app, &cfg, 3u) == FW_OK);
  TT_CHECK(fw_app_attach_nvm(&g_app, &NVM) == FW_APP_NVM_EMPTY);
  fw_ctrl_t *c = fw_app_ctrl(&g_app);
  fw_config_t mine = *fw_get_config(c);
  mine.estimator.u_inj_V = 25.0f;
  TT_CHECK(fw_set_config(c, &mine, NULL) == FW_OK);
  /* count the bytes a whole save changes */
  g_flash.erases = g_flash.programs = 0;
  TT_CHECK(fw_app_nvm_save(&g_app) == CO_ABORT_NONE);
  uint8_t whole[PAGE];
  memcpy(whole, g_flash.mem, PAGE);
  size_t blen = 0u;
  uint8_t tmp[PAGE];
  TT_CHECK(nvm_page_read(&PAGEDEV, tmp, sizeof tmp, &blen) == FW_NVM_OK);
  const long total = (long)PAGE + (long)((blen + UNIT - 1u) / UNIT * UNIT) + (long)UNIT;
  int loaded = 0, defaults = 0, wrong = 0;
  for (long cut = 0; cut <= total; cut += (cut < PAGE - 16 ? 61 : 1)) {
    memset(g_flash.mem, 0x00, PAGE); /* an old block of zeros: any stale content */
    g_flash.mem[0] = 0x12;
    g_flash.budget = cut;
    g_flash.dead = 0;
    (void)fw_app_nvm_save(&g_app);
    g_flash.budget = -1;
    g_flash.dead = 0;
    TT_CHECK(fw_app_init(&g_app2, &cfg, 3u) == FW_OK);
    fw_app_nvm_state_t st = fw_app_attach_nvm(&g_app2, &NVM);
    float u = fw_get_config(fw_app_ctrl(&g_app2))->estimator.u_inj_V;
    if (st == FW_APP_NVM_LOADED) {
      /* only a write whose block and header are all there (its last header
         bytes may be 0xFF already: programming them changes nothing) */
      loaded++;
      wrong += u != 25.0f || memcmp(g_flash.mem, whole, UNIT + blen) != 0;
    } else {
      defaults++;
      wrong += (st != FW_APP_NVM_EMPTY && st != FW_APP_NVM_BAD_CRC) || u != cfg.estimator.u_inj_V;
    }
  }
  TT_CHECK(wrong == 0);
  TT_CHECK(loaded >= 1 && loaded <= (int)UNIT); /* the complete write (and its 0xFF tail) */
  TT_CHECK(defaults > 100);  /* torn all the way through */
  TT_CHECK(g_flash.bad_prog == 0);
}

int main(void) {
  TT_RUN(test_roundtrip_and_erase);
  TT_RUN(test_torn_writes_boot_on_defaults);
  return TT_SUMMARY();
}
