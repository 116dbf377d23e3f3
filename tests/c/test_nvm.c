/**
 * @file test_nvm.c
 * @brief Non-volatile parameters (CiA 301 0x1010 'save' / 0x1011 'load'):
 *        signatures, save and boot, the block's CRC / product / version /
 *        content checks (a rejected block changes nothing), erase + NMT
 *        reset node, reset communication, refusal while enabled, a port
 *        without storage (the blank port) and a failing medium.
 *
 * The storage is a RAM port defined here (its two functions are handed to
 * fw_app_attach_nvm like a board's); the blank port is the real one.
 * References: the CRC against the catalogued check value of CRC-32/ISO-HDLC,
 * stored values against what was written by SDO.
 */
#include <string.h>

#include "../../firmware_c/port/blank/fw_port_blank.c"
#include "pmlsm/fw_app.h"
#include "tinytest.h"

#define NID 5u
#define SAVE CO_SIGNATURE_SAVE
#define LOAD CO_SIGNATURE_LOAD

typedef struct {
  uint8_t data[FW_APP_NVM_LEN];
  size_t len;
  int present;
  int fail_write;
  int writes;
} ram_store_t;

static ram_store_t g_ram;
static fw_app_t g_app; /* large: trace buffer */
static fw_inputs_t g_in;
static fw_outputs_t g_out;

static fw_nvm_status_t ram_read(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len) {
  ram_store_t *s = (ram_store_t *)(void *)port;
  *len = 0u;
  if (!s->present) {
    return FW_NVM_EMPTY;
  }
  if (s->len > cap) {
    return FW_NVM_ERROR;
  }
  memcpy(buf, s->data, s->len);
  *len = s->len;
  return FW_NVM_OK;
}

static fw_nvm_status_t ram_write(fw_port_t *port, const uint8_t *data, size_t len) {
  ram_store_t *s = (ram_store_t *)(void *)port;
  s->writes++;
  if (s->fail_write) {
    return FW_NVM_ERROR;
  }
  if (len == 0u) {
    s->present = 0;
    s->len = 0u;
    return FW_NVM_OK;
  }
  if (len > sizeof s->data) {
    return FW_NVM_ERROR;
  }
  memcpy(s->data, data, len);
  s->len = len;
  s->present = 1;
  return FW_NVM_OK;
}

static const fw_app_nvm_t RAM_NVM = {(fw_port_t *)(void *)&g_ram, ram_read, ram_write};

#include "app_harness.h"

static uint32_t f2u(float f) {
  uint32_t u;
  memcpy(&u, &f, 4);
  return u;
}

static float u2f(uint32_t u) {
  float f;
  memcpy(&f, &u, 4);
  return f;
}

static void nmt(uint8_t cmd) {
  uint8_t d[2] = {cmd, (uint8_t)NID};
  rx(0x000, 2, d);
  step_n(1);
}

/* a freshly powered drive with the factory configuration (fw_config_default) */
static fw_app_nvm_state_t boot(const fw_app_nvm_t *nvm) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  memset(&g_in, 0, sizeof g_in);
  g_in.u_dc_V = 300.0f;
  TT_CHECK(fw_app_init(&g_app, &cfg, NID) == FW_OK);
  const fw_app_nvm_state_t st = fw_app_attach_nvm(&g_app, nvm);
  step_n(2); /* out of NOT READY TO SWITCH ON (physical inputs: no zero calibration) */
  return st;
}

static float cfg_u_inj(void) { return fw_get_config(fw_app_ctrl(&g_app))->estimator.u_inj_V; }

static void put_le32(uint8_t *p, uint32_t v) {
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
  p[2] = (uint8_t)(v >> 16);
  p[3] = (uint8_t)(v >> 24);
}

static uint32_t get_le32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
         ((uint32_t)p[3] << 24);
}

/* re-seal a tampered block so only the tampered field can be the reason */
static void reseal(void) {
  put_le32(&g_ram.data[g_ram.len - 4u], fw_app_crc32(g_ram.data, g_ram.len - 4u));
}

/* offset of the value of record (index, sub) in the stored block, 0 if absent */
static size_t find_record(uint16_t index, uint8_t sub) {
  size_t n = 24u + 2u + sizeof(fw_config_t);
  uint32_t count = (uint32_t)g_ram.data[n] | ((uint32_t)g_ram.data[n + 1u] << 8);
  n += 2u;
  for (uint32_t k = 0; k < count && n + 4u <= g_ram.len - 4u; k++) {
    uint16_t i = (uint16_t)(g_ram.data[n] | (g_ram.data[n + 1u] << 8));
    if (i == index && g_ram.data[n + 2u] == sub) {
      return n + 4u;
    }
    n += 4u + g_ram.data[n + 3u];
  }
  return 0u;
}

/* save: u_inj_V 25 V, producer heartbeat 250 ms, device tag "rig-7" */
static void save_reference_block(void) {
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_EMPTY);
  TT_CHECK(sdo_write(0x2010, 1, f2u(25.0f), 4) == 0);
  TT_CHECK(sdo_write(0x1017, 0, 250u, 2) == 0);
  TT_CHECK(co_node_write(fw_app_node(&g_app), 0x2042, 0, (const uint8_t *)"rig-7", 5u) ==
           CO_ABORT_NONE);
  TT_CHECK(sdo_write(0x1010, 1, SAVE, 4) == 0);
  TT_CHECK(g_ram.present && g_ram.writes == 1);
}

static void test_crc32_check_value(void) {
  TT_CHECK(fw_app_crc32((const uint8_t *)"123456789", 9u) == 0xCBF43926u);
  TT_CHECK(fw_app_crc32((const uint8_t *)"", 0u) == 0u);
}

static void test_no_storage(void) {
  memset(&g_ram, 0, sizeof g_ram);
  TT_CHECK(boot(NULL) == FW_APP_NVM_NONE);
  TT_CHECK(sdo_read(0x1010, 1) == 0u && sdo_read(0x1011, 1) == 0u);
  TT_CHECK(sdo_write(0x1010, 1, SAVE, 4) == 0x08000020u);
  TT_CHECK(sdo_write(0x1011, 1, LOAD, 4) == 0x08000020u);
  /* the blank port: no non-volatile memory */
  const fw_app_nvm_t blank = {NULL, fw_port_nvm_read, fw_port_nvm_write};
  TT_CHECK(boot(&blank) == FW_APP_NVM_NONE);
  TT_CHECK(sdo_read(0x1010, 1) == 0u);
  TT_CHECK(sdo_write(0x1010, 1, SAVE, 4) == 0x08000020u);
  TT_CHECK(fw_app_nvm_save(&g_app) == CO_ABORT_APP);
}

static void test_signatures(void) {
  memset(&g_ram, 0, sizeof g_ram);
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_EMPTY);
  TT_CHECK(sdo_read(0x1010, 0) == 1u); /* highest sub-index */
  TT_CHECK(sdo_read(0x1010, 1) == 1u && sdo_read(0x1011, 1) == 1u);
  TT_CHECK(sdo_write(0x1010, 1, 0x12345678u, 4) == 0x08000020u);
  TT_CHECK(sdo_write(0x1010, 1, LOAD, 4) == 0x08000020u); /* the other one */
  TT_CHECK(sdo_write(0x1011, 1, SAVE, 4) == 0x08000020u);
  TT_CHECK(sdo_write(0x1010, 1, 0x7661u, 2) != 0u);       /* "sa": wrong length */
  TT_CHECK(g_ram.writes == 0 && !g_ram.present);
  TT_CHECK(sdo_write(0x1010, 1, SAVE, 4) == 0);
  TT_CHECK(g_ram.writes == 1 && g_ram.present);
  TT_CHECK(sdo_read(0x1010, 1) == 1u); /* the signature is not stored */
}

static void test_save_then_boot(void) {
  memset(&g_ram, 0, sizeof g_ram);
  save_reference_block();
  TT_CHECK(g_ram.len > 24u && g_ram.len <= FW_APP_NVM_LEN);
  TT_CHECK(get_le32(&g_ram.data[g_ram.len - 4u]) == fw_app_crc32(g_ram.data, g_ram.len - 4u));
  /* power cycle: the factory configuration is given, the stored one is used */
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_LOADED);
  TT_CHECK(fw_app_nvm_state(&g_app) == FW_APP_NVM_LOADED);
  TT_CHECK_NEAR(cfg_u_inj(), 25.0, 0.0);
  TT_CHECK_NEAR(u2f(sdo_read(0x2010, 1)), 25.0, 0.0);
  TT_CHECK(sdo_read(0x1017, 0) == 250u);
  uint8_t tag[32];
  size_t n = sizeof tag;
  TT_CHECK(co_node_read(fw_app_node(&g_app), 0x2042, 0, tag, &n) == CO_ABORT_NONE);
  TT_CHECK(n == 5u && memcmp(tag, "rig-7", 5u) == 0);
  /* commands are not configuration: the mode and the references boot at their defaults */
  TT_CHECK(sdo_read(0x6060, 0) == 9u && sdo_read(0x60FF, 0) == 0u);
}

static void expect_rejected(fw_app_nvm_state_t why) {
  TT_CHECK(boot(&RAM_NVM) == why);
  TT_CHECK_NEAR(cfg_u_inj(), 50.0, 0.0); /* fw_config_default */
  TT_CHECK_NEAR(u2f(sdo_read(0x2010, 1)), 50.0, 0.0);
  TT_CHECK(sdo_read(0x1017, 0) == 100u); /* od.yaml default: no object was taken either */
}

static void test_rejected_blocks_change_nothing(void) {
  memset(&g_ram, 0, sizeof g_ram);
  save_reference_block();
  ram_store_t good = g_ram;
  size_t cfg_at = 24u + 2u;
  size_t rec_at = cfg_at + sizeof(fw_config_t) + 2u; /* first record: index, sub, len, value */

  g_ram.data[g_ram.len / 2u] ^= 0x01u; /* one bit flipped */
  expect_rejected(FW_APP_NVM_BAD_CRC);
  g_ram = good;
  g_ram.len -= 1u; /* torn write */
  expect_rejected(FW_APP_NVM_BAD_CRC);
  g_ram = good;
  g_ram.data[0] ^= 0xFFu; /* not our magic, even with a valid CRC */
  reseal();
  expect_rejected(FW_APP_NVM_BAD_CRC);

  g_ram = good;
  put_le32(&g_ram.data[8], 0x11223344u); /* another product */
  reseal();
  expect_rejected(FW_APP_NVM_BAD_PRODUCT);
  g_ram = good;
  put_le32(&g_ram.data[12], FW_VERSION_U32 + 1u); /* another firmware version */
  reseal();
  expect_rejected(FW_APP_NVM_BAD_VERSION);
  g_ram = good;
  g_ram.data[16] ^= 0x01u; /* another fw_config_t layout */
  reseal();
  expect_rejected(FW_APP_NVM_BAD_VERSION);

  g_ram = good; /* a configuration the firmware refuses: u_inj_V below its 1 V minimum */
  const fw_config_field_t *f = fw_config_field_find("u_inj_V");
  TT_CHECK(f != NULL);
  if (f != NULL) {
    put_le32(&g_ram.data[cfg_at + f->offset], f2u(-5.0f));
  }
  reseal();
  expect_rejected(FW_APP_NVM_BAD_CONTENT);
  g_ram = good; /* an object record turned into a command (controlword) */
  g_ram.data[rec_at] = 0x40;
  g_ram.data[rec_at + 1u] = 0x60;
  g_ram.data[rec_at + 2u] = 0x00;
  reseal();
  expect_rejected(FW_APP_NVM_BAD_CONTENT);
  g_ram = good; /* an object value out of its od.yaml range: 9 telemetry signals (max 8) */
  size_t at = find_record(0x2060, 2);
  TT_CHECK(at != 0u && g_ram.data[at] == 4u);
  g_ram.data[at] = 9u;
  reseal();
  expect_rejected(FW_APP_NVM_BAD_CONTENT);
  g_ram = good; /* a record whose length is not its object's (u32 stored as 2 bytes) */
  TT_CHECK(g_ram.data[rec_at + 3u] == 4u);
  g_ram.data[rec_at + 3u] = 2u;
  reseal();
  expect_rejected(FW_APP_NVM_BAD_CONTENT);

  g_ram = good; /* and the untouched block still loads */
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_LOADED);
}

static void test_erase_and_reset_node(void) {
  memset(&g_ram, 0, sizeof g_ram);
  save_reference_block();
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_LOADED);
  TT_CHECK(sdo_write(0x2010, 1, f2u(30.0f), 4) == 0); /* changed, not saved */
  nmt(0x81);                                            /* reset node: as after power-up */
  TT_CHECK_NEAR(cfg_u_inj(), 25.0, 0.0);
  TT_CHECK_NEAR(u2f(sdo_read(0x2010, 1)), 25.0, 0.0);
  TT_CHECK(sdo_read(0x1017, 0) == 250u && sdo_read(0x1010, 1) == 1u);
  TT_CHECK(sdo_write(0x1011, 1, LOAD, 4) == 0);
  TT_CHECK(!g_ram.present);
  TT_CHECK_NEAR(cfg_u_inj(), 25.0, 0.0); /* CiA 301: the defaults apply after the reset */
  nmt(0x81);
  TT_CHECK(fw_app_nvm_state(&g_app) == FW_APP_NVM_EMPTY);
  TT_CHECK_NEAR(cfg_u_inj(), 50.0, 0.0);
  TT_CHECK(sdo_read(0x1017, 0) == 100u);
}

static void test_reset_communication_reloads_comm_objects(void) {
  memset(&g_ram, 0, sizeof g_ram);
  save_reference_block();
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_LOADED);
  TT_CHECK(sdo_write(0x1017, 0, 300u, 2) == 0);
  TT_CHECK(sdo_write(0x2010, 1, f2u(30.0f), 4) == 0);
  nmt(0x82); /* reset communication: stored communication objects, application untouched */
  TT_CHECK(sdo_read(0x1017, 0) == 250u);
  TT_CHECK_NEAR(cfg_u_inj(), 30.0, 0.0);
  memset(&g_ram, 0, sizeof g_ram);
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_EMPTY);
  TT_CHECK(sdo_write(0x1017, 0, 300u, 2) == 0);
  nmt(0x82); /* nothing stored: the od.yaml default */
  TT_CHECK(sdo_read(0x1017, 0) == 100u);
}

static void test_refused_while_enabled_and_failing_medium(void) {
  memset(&g_ram, 0, sizeof g_ram);
  TT_CHECK(boot(&RAM_NVM) == FW_APP_NVM_EMPTY);
  TT_CHECK(sdo_write(0x6040, 0, 0x06, 2) == 0);
  TT_CHECK(sdo_write(0x6040, 0, 0x07, 2) == 0);
  TT_CHECK(sdo_write(0x6040, 0, 0x0F, 2) == 0);
  step_n(2);
  TT_CHECK(fw_state(fw_app_ctrl(&g_app)) == FW_CIA402_OPERATION_ENABLED);
  TT_CHECK(sdo_write(0x1010, 1, SAVE, 4) == 0x08000022u);
  TT_CHECK(g_ram.writes == 0);
  TT_CHECK(sdo_write(0x6040, 0, 0x00, 2) == 0);
  step_n(2);
  TT_CHECK(sdo_write(0x1010, 1, SAVE, 4) == 0);
  g_ram.fail_write = 1;
  TT_CHECK(sdo_write(0x1010, 1, SAVE, 4) == 0x08000020u);
  TT_CHECK(sdo_write(0x1011, 1, LOAD, 4) == 0x08000020u);
  /* attach after the first step is refused: booting again would restart the core */
  TT_CHECK(fw_app_attach_nvm(&g_app, NULL) == FW_APP_NVM_EMPTY);
  TT_CHECK(sdo_read(0x1010, 1) == 1u);
}

int main(void) {
  TT_RUN(test_crc32_check_value);
  TT_RUN(test_no_storage);
  TT_RUN(test_signatures);
  TT_RUN(test_save_then_boot);
  TT_RUN(test_rejected_blocks_change_nothing);
  TT_RUN(test_erase_and_reset_node);
  TT_RUN(test_reset_communication_reloads_comm_objects);
  TT_RUN(test_refused_while_enabled_and_failing_medium);
  return TT_SUMMARY();
}
