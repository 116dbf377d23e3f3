/**
 * @file test_g474_nvm.c
 * @brief The NUCLEO-G474RE's parameter page with the G4's flash ECC, modelled
 *        here: the page is 2 KB (dual-bank mode) programmed a double word at a
 *        time (g474_port.c, nvm_program); power lost in the middle of a double
 *        word's program operation leaves that double word with an
 *        uncorrectable ECC error, and reading it raises the NMI. The port's
 *        answer (g474_nmi marks the page, nvm_view then returns
 *        g474_nvm_bad_page) is modelled by this test's view; what is tested is
 *        that the answer, through the real _common/nvm_page.c and the drive
 *        application's boot, boots on the defaults (never on a mix) and that
 *        the next 'save' stores a good block again.
 */
#include <string.h>

#include "../../firmware_c/boards/_common/nvm_page.c"
#include "../../firmware_c/boards/nucleo_g474re/g474_calc.c"
#include "../../firmware_c/port/blank/fw_port_blank.c"
#include "pmlsm/fw_app.h"
#include "tinytest.h"

#define PAGE 2048u
#define DW 8u

typedef struct {
  uint8_t mem[PAGE];
  uint8_t ecc_bad[PAGE / DW]; /* double words torn in their program operation */
  long budget;                /* double-word operations before power is lost (-1: none) */
  int dead;
  int nmi; /* NMIs the reads raised (in the page) */
} flash_t;

static flash_t g_f;

static int g_torn_mid; /* 1: power is lost in the middle of the double word */

static bool f_erase(void *ctx) {
  flash_t *f = (flash_t *)ctx;
  if (f->dead)
    return true;
  if (f->budget == 0) { /* erase cut: the page is a mess, with ECC errors */
    f->dead = 1;
    for (uint32_t i = 0; i < PAGE / DW; i += 3u)
      f->ecc_bad[i] = 1u;
    return true;
  }
  if (f->budget > 0)
    f->budget--;
  memset(f->mem, 0xFF, PAGE);
  memset(f->ecc_bad, 0, sizeof f->ecc_bad);
  return true;
}

static bool f_program(void *ctx, uint32_t off, const uint8_t *d, uint32_t len) {
  flash_t *f = (flash_t *)ctx;
  for (uint32_t i = 0; i < len; i += DW) {
    if (f->dead)
      return true;
    if (f->budget == 0) {
      f->dead = 1;
      if (g_torn_mid) {
        f->mem[off + i] &= d[i]; /* some bits of it, and its ECC bits half-written */
        f->ecc_bad[(off + i) / DW] = 1u;
      }
      return true;
    }
    if (f->budget > 0)
      f->budget--;
    for (uint32_t k = 0; k < DW; k++)
      f->mem[off + i + k] &= d[i + k];
  }
  return true;
}

/* the port's view: a read of every double word; one with an ECC double error
   raises the NMI, which marks the page; a marked page reads as the bad image */
static const uint8_t *f_view(void *ctx) {
  flash_t *f = (flash_t *)ctx;
  int bad = 0;
  for (uint32_t i = 0; i < PAGE / DW; i++) {
    if (f->ecc_bad[i]) {
      f->nmi++;
      bad = 1;
    }
  }
  return bad ? g474_nvm_bad_page : f->mem;
}

static const nvm_page_t PAGEDEV = {&g_f, PAGE, DW, f_erase, f_program, f_view};

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

static void test_bad_page_image_is_rejected(void) {
  /* a page the NMI marked reads as a one-byte block: the CRC rejects it */
  uint8_t buf[PAGE];
  size_t len = 0u;
  nvm_page_t bad = PAGEDEV;
  memset(g_f.ecc_bad, 1, sizeof g_f.ecc_bad);
  TT_CHECK(nvm_page_read(&bad, buf, sizeof buf, &len) == FW_NVM_OK && len == 1u);
  fw_config_t cfg;
  fw_config_default(&cfg);
  TT_CHECK(fw_app_init(&g_app, &cfg, 1u) == FW_OK);
  TT_CHECK(fw_app_attach_nvm(&g_app, &NVM) == FW_APP_NVM_BAD_CRC);
  /* the write after it verifies through the same view: an error while the page
     stays marked, success once the erase cleared the bad double words */
  memset(g_f.ecc_bad, 0, sizeof g_f.ecc_bad);
  g_f.budget = -1;
  g_f.dead = 0;
  TT_CHECK(fw_app_nvm_save(&g_app) == CO_ABORT_NONE);
  TT_CHECK(fw_app_init(&g_app2, &cfg, 1u) == FW_OK);
  TT_CHECK(fw_app_attach_nvm(&g_app2, &NVM) == FW_APP_NVM_LOADED);
}

/* a save cut after every double word, mid-operation (ECC error) or between
   two operations: the next boot is on the defaults or on the new block whole */
static void test_torn_double_words_boot_on_defaults(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  g474_board_config(&cfg, 1u); /* the board's own defaults */
  memset(&g_f, 0xFF, sizeof g_f.mem);
  memset(g_f.ecc_bad, 0, sizeof g_f.ecc_bad);
  g_f.budget = -1;
  g_f.dead = 0;
  TT_CHECK(fw_app_init(&g_app, &cfg, 1u) == FW_OK);
  TT_CHECK(fw_app_attach_nvm(&g_app, &NVM) == FW_APP_NVM_EMPTY);
  fw_ctrl_t *c = fw_app_ctrl(&g_app);
  fw_config_t mine = *fw_get_config(c);
  mine.estimator.u_inj_V = 6.5f;
  TT_CHECK(fw_set_config(c, &mine, NULL) == FW_OK);
  TT_CHECK(fw_app_nvm_save(&g_app) == CO_ABORT_NONE);
  size_t blen = 0u;
  uint8_t tmp[PAGE];
  TT_CHECK(nvm_page_read(&PAGEDEV, tmp, sizeof tmp, &blen) == FW_NVM_OK);
  const long ops = 1 + (long)((blen + DW - 1u) / DW) + 1; /* erase, block, header */
  int loaded = 0, defaults = 0, wrong = 0, nmis = 0;
  for (g_torn_mid = 0; g_torn_mid <= 1; g_torn_mid++) {
    for (long cut = 0; cut <= ops; cut++) {
      memset(g_f.mem, 0x00, PAGE); /* an old block: stale content */
      memset(g_f.ecc_bad, 0, sizeof g_f.ecc_bad);
      g_f.nmi = 0;
      g_f.budget = cut;
      g_f.dead = 0;
      (void)fw_app_nvm_save(&g_app);
      g_f.budget = -1;
      g_f.dead = 0;
      TT_CHECK(fw_app_init(&g_app2, &cfg, 1u) == FW_OK);
      const fw_app_nvm_state_t st = fw_app_attach_nvm(&g_app2, &NVM);
      const float u = fw_get_config(fw_app_ctrl(&g_app2))->estimator.u_inj_V;
      nmis += g_f.nmi > 0;
      if (st == FW_APP_NVM_LOADED) {
        loaded++;
        wrong += u != 6.5f;
      } else {
        defaults++;
        wrong += (st != FW_APP_NVM_EMPTY && st != FW_APP_NVM_BAD_CRC) || u != cfg.estimator.u_inj_V;
      }
    }
  }
  TT_CHECK(wrong == 0);
  TT_CHECK(loaded == 2); /* the two uncut saves */
  TT_CHECK(defaults >= 2 * (int)(ops - 1));
  TT_CHECK(nmis >= (int)ops); /* the mid-operation cuts did raise ECC errors */
}

int main(void) {
  TT_RUN(test_bad_page_image_is_rejected);
  TT_RUN(test_torn_double_words_boot_on_defaults);
  return TT_SUMMARY();
}
