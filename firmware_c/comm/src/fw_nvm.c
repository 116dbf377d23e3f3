/**
 * @file fw_nvm.c
 * @brief The drive application's non-volatile parameter block (CiA 301 0x1010
 *        store / 0x1011 restore, fw_app.h): CRC-32, the configuration layout's
 *        hash, the block's build and check, the boot from it, and the handlers
 *        of 0x1010:1 and 0x1011:1 (od.yaml hook:, outside the lock).
 */
#include <string.h>

#include "fw_app_hooks.h"
#include "fw_app_internal.h"
#include "pmlsm/fw_app.h"

#define FW_APP_NVM_MAGIC 0x4D564E50u /* "PNVM" */
#define FW_APP_NVM_FORMAT 1u
/* header: magic u32, format u16, reserved u16, product code u32, firmware
   version u32, layout hash u32, payload length u32 (all little endian) */
#define FW_APP_NVM_HDR 24u
#define FW_APP_NVM_VALUE_MAX 64u /* largest storable object (bytes) */

static uint32_t fw_app_crc32_feed(uint32_t crc, const uint8_t *data, size_t len) {
  for (size_t i = 0u; i < len; i++) {
    crc ^= data[i];
    for (uint32_t k = 0u; k < 8u; k++) {
      crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
  }
  return crc;
}

uint32_t fw_app_crc32(const uint8_t *data, size_t len) {
  if (data == NULL) {
    return 0u;
  }
  return ~fw_app_crc32_feed(0xFFFFFFFFu, data, len);
}

/** Hash of the fw_config_t layout (field names, offsets, kinds, size): a
 *  block written by a build with another layout is refused even when the
 *  firmware version number was not raised. */
static uint32_t fw_app_nvm_layout(void) {
  uint32_t crc = 0xFFFFFFFFu;
  uint8_t w[5];
  for (size_t i = 0u; i < fw_config_field_count(); i++) {
    const fw_config_field_t *f = fw_config_field(i);
    if (f == NULL || f->name == NULL) {
      continue;
    }
    crc = fw_app_crc32_feed(crc, (const uint8_t *)f->name, strlen(f->name) + 1u);
    co_le_put(w, 4u, (uint32_t)f->offset);
    w[4] = (uint8_t)(f->is_int | (uint8_t)(f->is_signed << 1)); /* float 0, u32 1, i32 3 */
    crc = fw_app_crc32_feed(crc, w, sizeof w);
  }
  co_le_put(w, 4u, (uint32_t)sizeof(fw_config_t));
  return ~fw_app_crc32_feed(crc, w, 4u);
}

/** Objects stored besides the configuration: writable, not a command
 *  (od.yaml `command`: controlword, mode, targets, store and trace commands),
 *  not a view of a fw_config_t field (the configuration is stored whole). */
static bool fw_app_nvm_storable(uint16_t pos) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (e == NULL || (e->access & CO_ACC_W) == 0u || (e->access & CO_ACC_CONST) != 0u ||
      (e->flags & CO_FLAG_CMD) != 0u || e->size > FW_APP_NVM_VALUE_MAX) {
    return false;
  }
  if (e->index == 0x2002u) { /* adaptive SOGI on/off: a view of the extractor field */
    return false;
  }
  for (uint32_t k = 0u; k < CO_OD_CFG_COUNT; k++) {
    if (co_od_cfg_links[k].pos == pos) {
      return false;
    }
  }
  return true;
}

/** Build the block in app->nvm_buf; returns its length, 0 when it does not fit. */
static size_t fw_app_nvm_build(fw_app_t *app) {
  uint8_t *b = app->nvm_buf;
  const size_t cap = sizeof app->nvm_buf;
  const fw_config_t *cfg = fw_get_config(&app->ctrl);
  if (cfg == NULL || FW_APP_NVM_HDR + 4u + sizeof *cfg + 4u > cap) {
    return 0u;
  }
  size_t n = FW_APP_NVM_HDR;
  co_le_put(&b[n], 2u, (uint32_t)sizeof *cfg);
  n += 2u;
  memcpy(&b[n], cfg, sizeof *cfg);
  n += sizeof *cfg;
  size_t count_at = n;
  uint32_t count = 0u;
  n += 2u;
  for (uint16_t pos = 0u; pos < co_od_count(); pos++) {
    if (!fw_app_nvm_storable(pos)) {
      continue;
    }
    const co_od_entry_t *e = co_od_entry(pos);
    uint8_t val[FW_APP_NVM_VALUE_MAX];
    size_t len = co_od_load(app->node.od, sizeof app->node.od, pos, val, sizeof val);
    if (n + 4u + len + 4u > cap) {
      return 0u;
    }
    co_le_put(&b[n], 2u, e->index);
    b[n + 2u] = e->sub;
    b[n + 3u] = (uint8_t)len;
    memcpy(&b[n + 4u], val, len);
    n += 4u + len;
    count++;
  }
  co_le_put(&b[count_at], 2u, count);
  co_le_put(&b[0], 4u, FW_APP_NVM_MAGIC);
  co_le_put(&b[4], 2u, FW_APP_NVM_FORMAT);
  co_le_put(&b[6], 2u, 0u);
  co_le_put(&b[8], 4u, co_node_get_u32(&app->node, CO_OD_1018_02));
  co_le_put(&b[12], 4u, FW_VERSION_U32);
  co_le_put(&b[16], 4u, fw_app_nvm_layout());
  co_le_put(&b[20], 4u, (uint32_t)(n - FW_APP_NVM_HDR));
  co_le_put(&b[n], 4u, fw_app_crc32(b, n));
  return n + 4u;
}

/** Check a block read into app->nvm_buf without changing anything; on
 *  FW_APP_NVM_LOADED *cfg is its configuration and *records the offset of
 *  its first object record. */
static fw_app_nvm_state_t fw_app_nvm_check(const fw_app_t *app, size_t len, fw_config_t *cfg,
                                           size_t *records) {
  const uint8_t *b = app->nvm_buf;
  if (len < FW_APP_NVM_HDR + 4u || len > sizeof app->nvm_buf) {
    return FW_APP_NVM_BAD_CRC;
  }
  size_t end = len - 4u;
  if (co_le_get(&b[0], 4u) != FW_APP_NVM_MAGIC || co_le_get(&b[4], 2u) != FW_APP_NVM_FORMAT ||
      co_le_get(&b[20], 4u) != (uint32_t)(end - FW_APP_NVM_HDR) ||
      fw_app_crc32(b, end) != co_le_get(&b[end], 4u)) {
    return FW_APP_NVM_BAD_CRC;
  }
  if (co_le_get(&b[8], 4u) != co_node_get_u32(&app->node, CO_OD_1018_02)) {
    return FW_APP_NVM_BAD_PRODUCT;
  }
  size_t n = FW_APP_NVM_HDR;
  if (co_le_get(&b[12], 4u) != FW_VERSION_U32 || co_le_get(&b[16], 4u) != fw_app_nvm_layout() ||
      n + 2u + sizeof *cfg + 2u > end || co_le_get(&b[n], 2u) != (uint32_t)sizeof *cfg) {
    return FW_APP_NVM_BAD_VERSION;
  }
  n += 2u;
  memcpy(cfg, &b[n], sizeof *cfg);
  n += sizeof *cfg;
  fw_config_issue_t issue;
  fw_status_t st = fw_config_check(cfg, &issue);
  if (st != FW_OK && st != FW_ERR_SALIENCY) { /* saliency: stored as fw_set_config does */
    return FW_APP_NVM_BAD_CONTENT;
  }
  uint32_t count = co_le_get(&b[n], 2u);
  n += 2u;
  *records = n;
  for (uint32_t k = 0u; k < count; k++) {
    uint16_t pos;
    if (n + 4u > end) {
      return FW_APP_NVM_BAD_CONTENT;
    }
    size_t rl = b[n + 3u];
    if (n + 4u + rl > end ||
        co_od_find((uint16_t)co_le_get(&b[n], 2u), b[n + 2u], &pos) != CO_OD_OK ||
        !fw_app_nvm_storable(pos) || co_od_check(pos, &b[n + 4u], rl) != CO_ABORT_NONE) {
      return FW_APP_NVM_BAD_CONTENT;
    }
    n += 4u + rl;
  }
  return n == end ? FW_APP_NVM_LOADED : FW_APP_NVM_BAD_CONTENT;
}

/** Store the checked object records in the OD (comm_only: 0x1000..0x1FFF). */
static void fw_app_nvm_apply_records(fw_app_t *app, size_t len, size_t n, bool comm_only) {
  const uint8_t *b = app->nvm_buf;
  size_t end = len - 4u;
  while (n + 4u <= end) {
    uint16_t pos;
    uint16_t index = (uint16_t)co_le_get(&b[n], 2u);
    size_t rl = b[n + 3u];
    if ((!comm_only || index < 0x2000u) && co_od_find(index, b[n + 2u], &pos) == CO_OD_OK) {
      co_od_store(app->node.od, sizeof app->node.od, pos, &b[n + 4u], rl);
    }
    n += 4u + rl;
  }
}

/** Boot from the stored block: configuration and objects (comm_only: the
 *  communication objects alone, for NMT reset communication). Returns true
 *  when it started the core with the stored configuration. */
bool fw_app_nvm_boot(fw_app_t *app, bool comm_only) {
  if (app->nvm.read == NULL) {
    app->nvm_supported = 0u;
    app->nvm_state = (uint8_t)FW_APP_NVM_NONE;
    return false;
  }
  size_t len = 0u;
  fw_nvm_status_t st = app->nvm.read(app->nvm.port, app->nvm_buf, sizeof app->nvm_buf, &len);
  fw_app_nvm_state_t state = FW_APP_NVM_READ_ERROR;
  fw_config_t cfg;
  size_t records = 0u;
  app->nvm_supported = st != FW_NVM_UNSUPPORTED ? 1u : 0u;
  if (st == FW_NVM_OK) {
    state = fw_app_nvm_check(app, len, &cfg, &records);
  } else if (st == FW_NVM_EMPTY) {
    state = FW_APP_NVM_EMPTY;
  } else if (st == FW_NVM_UNSUPPORTED) {
    state = FW_APP_NVM_NONE;
  }
  if (!comm_only) {
    app->nvm_state = (uint8_t)state;
    if (state == FW_APP_NVM_LOADED) {
      (void)fw_app_start_core(app, &cfg);
    }
  }
  if (state == FW_APP_NVM_LOADED) {
    fw_app_nvm_apply_records(app, len, records, comm_only);
  }
  return !comm_only && state == FW_APP_NVM_LOADED;
}

fw_app_nvm_state_t fw_app_attach_nvm(fw_app_t *app, const fw_app_nvm_t *nvm) {
  if (app == NULL || !app->init_done) {
    return FW_APP_NVM_NONE;
  }
  if (app->step != 0u) { /* the boot is over: booting again would restart the core */
    return (fw_app_nvm_state_t)app->nvm_state;
  }
  if (nvm == NULL || nvm->read == NULL || nvm->write == NULL) {
    memset(&app->nvm, 0, sizeof app->nvm);
  } else {
    app->nvm = *nvm;
  }
  (void)fw_app_nvm_boot(app, false);
  fw_app_sync_static_od(app);
  co_node_set_u32(&app->node, CO_OD_6041_00, fw_statusword(&app->ctrl));
  return (fw_app_nvm_state_t)app->nvm_state;
}

fw_app_nvm_state_t fw_app_nvm_state(const fw_app_t *app) {
  return app != NULL ? (fw_app_nvm_state_t)app->nvm_state : FW_APP_NVM_NONE;
}

static co_abort_t fw_app_nvm_result(fw_nvm_status_t st) {
  return st == FW_NVM_OK ? CO_ABORT_NONE : CO_ABORT_APP;
}

co_abort_t fw_app_nvm_save(fw_app_t *app) {
  if (app == NULL || app->nvm.write == NULL || !app->nvm_supported) {
    return CO_ABORT_APP;
  }
  fw_cia402_state_t s = fw_state(&app->ctrl);
  if (s == FW_CIA402_OPERATION_ENABLED || s == FW_CIA402_QUICK_STOP_ACTIVE ||
      s == FW_CIA402_FAULT_REACTION_ACTIVE) {
    return CO_ABORT_DEVICE_STATE; /* a flash write stalls the control task */
  }
  size_t len = fw_app_nvm_build(app);
  if (len == 0u) {
    return CO_ABORT_APP;
  }
  return fw_app_nvm_result(app->nvm.write(app->nvm.port, app->nvm_buf, len));
}

co_abort_t fw_app_nvm_erase(fw_app_t *app) {
  if (app == NULL || app->nvm.write == NULL || !app->nvm_supported) {
    return CO_ABORT_APP;
  }
  return fw_app_nvm_result(app->nvm.write(app->nvm.port, NULL, 0u));
}

co_abort_t fw_app_hook_store(fw_app_t *app, uint32_t value) {
  (void)value; /* the signature ('save'), checked by the node */
  return fw_app_nvm_save(app);
}

co_abort_t fw_app_hook_restore(fw_app_t *app, uint32_t value) {
  (void)value; /* the signature ('load'), checked by the node */
  return fw_app_nvm_erase(app);
}
