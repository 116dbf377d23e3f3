/**
 * @file fw_app.c
 * @brief Drive application glue: fw_ctrl + CANopen node + serial link.
 */
#include "pmlsm/fw_app.h"

#include <float.h>
#include <math.h>
#include <string.h>

#ifndef PMLSM_BUILD_ID
#define PMLSM_BUILD_ID "dev"
#endif

#define FW_APP_MODE_CSV 9
#define FW_APP_MODE_CST 10

/* ---- helpers ------------------------------------------------------------- */

int32_t fw_app_round_i32(float v) {
  if (!(v == v)) {
    return 0;
  }
  if (v >= 2147483520.0f) {
    return INT32_MAX;
  }
  if (v <= -2147483520.0f) {
    return INT32_MIN;
  }
#if defined(FLT_EVAL_METHOD) && FLT_EVAL_METHOD == 0
  /* lrintf without the library call (about 100 instructions on the M4 per
     conversion): below 2^22, adding and subtracting 1.5 * 2^23 rounds to an
     integer in the current rounding mode, as lrintf does; from 2^23 on a float
     is an integer. Needs float arithmetic in float (FLT_EVAL_METHOD 0) and no
     reassociation (no -ffast-math); test_co_app compares it with lrintf. */
  float a = fabsf(v);
  if (a < 4194304.0f) {
    return (int32_t)((v + 12582912.0f) - 12582912.0f);
  }
  if (a >= 8388608.0f) {
    return (int32_t)v;
  }
#endif
  return (int32_t)lrintf(v);
}

static int32_t fw_app_sat_i16(float v) {
  int32_t x = fw_app_round_i32(v);
  return x > 32767 ? 32767 : (x < -32768 ? -32768 : x);
}

uint8_t fw_app_error_register(uint16_t code) {
  if (code == 0u) {
    return 0u;
  }
  uint8_t reg = 0x01u;
  switch (code & 0xF000u) {
  case 0x2000u:
    reg |= 0x02u;
    break;
  case 0x3000u:
    reg |= 0x04u;
    break;
  case 0x8000u:
    reg |= 0x10u;
    break;
  case 0xF000u:
    reg |= 0x80u;
    break;
  default:
    break;
  }
  return reg;
}

/* Time base: floor(steps * 1e6 / f_pwm) us modulo 2^32, converted in the
 * background from the period count the interrupt publishes (the interrupt
 * only counts): the periods since the last conversion at once, exactly what
 * adding 1e6 / f_pwm per period with the remainder carried gives; continuous
 * when the uint32 period counter wraps (49.7 h at 24 kHz). A change of
 * f_pwm (fw_app_start_core) converts up to the present period first. */
static uint32_t fw_app_time(fw_app_t *app, uint32_t step) {
  uint32_t f = app->f_pwm_Hz > 0u ? app->f_pwm_Hz : 1u;
  uint32_t d = step - app->time_step;
  if (d <= 4000u && app->us_rem <= 294967295u) {
    /* the usual pass (a few periods): the sum fits 32 bits, one hardware
       division instead of the 64-bit library one; the same result */
    uint32_t acc = app->us_rem + d * 1000000u;
    app->now_us += acc / f;
    app->us_rem = acc % f;
  } else {
    uint64_t acc = (uint64_t)app->us_rem + (uint64_t)d * 1000000u;
    app->now_us += (uint32_t)(acc / f); /* modulo 2^32 */
    app->us_rem = (uint32_t)(acc % f);
  }
  app->time_step = step;
  return app->now_us;
}

/* Complete the snapshot of a published period (once). */
static void fw_app_complete(fw_app_t *app, fw_app_period_t *p) {
  if (p->done != p->step + 1u) {
    fw_snapshot_complete(&app->ctrl, &p->snap, &p->raw);
    /* the reference sensor: scaled here, never seen by the core */
    p->snap.ref_pos_m = p->ref_status == (uint8_t)FW_REF_OK
                            ? (float)p->ref_count * CO_NODE_GET_F32(&app->node, 2091_02) -
                                  CO_NODE_GET_F32(&app->node, 2091_03)
                            : NAN;
    p->done = p->step + 1u;
  }
}

/* Complete every published period not processed yet: before the core's
 * configuration changes, so that they are completed with the configuration
 * they were stepped with. */
static void fw_app_complete_pending(fw_app_t *app) {
  uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_relaxed);
  uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_acquire);
  for (; tail != head; tail++) {
    fw_app_complete(app, &app->ring[tail % FW_APP_SNAP_RING]);
  }
}

/* The background's changes of the core happen inside this lock (fw_app.h). */
static uint32_t fw_app_lock(fw_app_t *app) {
  return app->lock.enter != NULL ? app->lock.enter(app->lock.port) : 0u;
}

static void fw_app_unlock(fw_app_t *app, uint32_t key) {
  if (app->lock.exit != NULL) {
    app->lock.exit(app->lock.port, key);
  }
}

void fw_app_attach_lock(fw_app_t *app, const fw_app_lock_t *lock) {
  if (app == NULL) {
    return;
  }
  if (lock == NULL || lock->enter == NULL || lock->exit == NULL) {
    memset(&app->lock, 0, sizeof app->lock);
  } else {
    app->lock = *lock;
  }
}

/* Periods the interrupt published and the background has not processed are
 * dropped when the core restarts (they describe the drive before it). */
static void fw_app_ring_discard(fw_app_t *app) {
  atomic_store_explicit(&app->ring_tail,
                        atomic_load_explicit(&app->ring_head, memory_order_acquire),
                        memory_order_release);
}

static const co_od_cfg_link_t *fw_app_cfg_link(uint16_t index, uint8_t sub) {
  uint16_t pos;
  if (co_od_find(index, sub, &pos) != CO_OD_OK) {
    return NULL;
  }
  for (uint32_t k = 0u; k < CO_OD_CFG_COUNT; k++) {
    if (co_od_cfg_links[k].pos == pos) {
      return &co_od_cfg_links[k];
    }
  }
  return NULL;
}

/** Field value as float (integer fields converted). */
static float fw_app_field_get(const fw_config_t *cfg, const fw_config_field_t *f) {
  const uint8_t *base = (const uint8_t *)cfg + f->offset;
  if (f->is_int && f->is_signed) {
    int32_t i;
    memcpy(&i, base, sizeof i);
    return (float)i;
  }
  if (f->is_int) {
    uint32_t u;
    memcpy(&u, base, sizeof u);
    return (float)u;
  }
  float x;
  memcpy(&x, base, sizeof x);
  return x;
}

/** Mirror the core's configuration into the OD (SI objects and the CiA 402
 *  objects that show a field in wire units: value x scale, rounded and held
 *  inside the entry's range). */
static void fw_app_sync_cfg_to_od(fw_app_t *app) {
  const fw_config_t *cfg = fw_get_config(&app->ctrl);
  if (cfg == NULL) {
    return;
  }
  for (uint32_t k = 0u; k < CO_OD_CFG_COUNT; k++) {
    const co_od_cfg_link_t *l = &co_od_cfg_links[k];
    const fw_config_field_t *f = fw_config_field_find(l->field);
    const co_od_entry_t *e = co_od_entry(l->pos);
    if (f == NULL || e == NULL) {
      continue;
    }
    if (e->type == CO_TYPE_REAL32) {
      co_node_set_f32(&app->node, l->pos, fw_app_field_get(cfg, f));
      continue;
    }
    if (f->is_int && l->scale == 1.0f) {
      /* the 32 bits as they are: a narrower entry keeps its low bytes, which are
         the value's two's complement for a signed field in the entry's range */
      uint32_t u;
      memcpy(&u, (const uint8_t *)cfg + f->offset, sizeof u);
      co_node_set_u32(&app->node, l->pos, u);
      continue;
    }
    float w = fw_app_field_get(cfg, f) * l->scale;
    if (w < (float)e->min_i) {
      w = (float)e->min_i;
    }
    if (w > (float)e->max_i) {
      w = (float)e->max_i;
    }
    if (e->type == CO_TYPE_U32) {
      co_node_set_u32(&app->node, l->pos, w >= 4294967040.0f ? UINT32_MAX : (uint32_t)lrintf(w));
    } else {
      co_node_set_i32(&app->node, l->pos, fw_app_round_i32(w));
    }
  }
  co_node_set_u32(&app->node, CO_OD_2002_00,
                  cfg->estimator.extractor == (uint32_t)FW_EXTRACTOR_SOGI_ADAPTIVE ? 1u : 0u);
}

static void fw_app_sync_static_od(fw_app_t *app) {
  /* CiA 301 0x1010/0x1011 read: bit 0 = saves / restores on command */
  co_node_set_u32(&app->node, CO_OD_1010_01, app->nvm_supported ? 1u : 0u);
  co_node_set_u32(&app->node, CO_OD_1011_01, app->nvm_supported ? 1u : 0u);
  co_node_set_u32(&app->node, CO_OD_2040_00, FW_VERSION_U32);
  co_node_set_str(&app->node, CO_OD_2041_00, PMLSM_BUILD_ID);
  co_node_set_u32(&app->node, CO_OD_2090_01, app->board_kind);
  co_node_set_str(&app->node, CO_OD_2090_02, app->board_name != NULL ? app->board_name : "");
  fw_app_sync_cfg_to_od(app);
}

static co_abort_t fw_app_status_abort(fw_status_t st) {
  switch (st) {
  case FW_OK:
    return CO_ABORT_NONE;
  case FW_ERR_STATE:
    return CO_ABORT_DEVICE_STATE;
  case FW_ERR_NULL:
    return CO_ABORT_GENERAL;
  default:
    return CO_ABORT_VALUE_RANGE;
  }
}

static void fw_app_trace_command(fw_app_t *app, uint8_t cmd) {
  co_node_t *n = &app->node;
  switch (cmd) {
  case 0u:
    fw_trace_stop(&app->trace);
    break;
  case 1u: {
    uint8_t ids[FW_SERIAL_MAX_SIGNALS];
    uint8_t cnt = (uint8_t)co_node_get_u32(n, CO_OD_2070_07);
    if (cnt > FW_SERIAL_MAX_SIGNALS) {
      cnt = FW_SERIAL_MAX_SIGNALS;
    }
    for (uint8_t k = 0u; k < cnt; k++) {
      ids[k] = (uint8_t)co_node_get_u32(n, (uint16_t)(CO_OD_2070_08 + k));
    }
    float dt = app->f_pwm_Hz > 0u ? 1.0f / (float)app->f_pwm_Hz : 0.0f;
    (void)fw_trace_arm(&app->trace, ids, cnt, co_node_get_u32(n, CO_OD_2070_06),
                       (uint8_t)co_node_get_u32(n, CO_OD_2070_03),
                       co_node_get_f32(n, CO_OD_2070_04),
                       (fw_trace_edge_t)co_node_get_u32(n, CO_OD_2070_05), dt);
    break;
  }
  case 2u: {
    /* at the next period the trace will sample: the oldest one the background
       has not processed yet, or the next the interrupt will publish */
    uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_relaxed);
    uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_acquire);
    fw_trace_trigger(&app->trace,
                     tail != head ? app->ring[tail % FW_APP_SNAP_RING].step : app->step);
    break;
  }
  case 3u:
    (void)fw_trace_upload_start(&app->trace);
    break;
  default:
    break;
  }
}

/* ---- non-volatile memory (CiA 301 0x1010 / 0x1011) ------------------------ */

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

static fw_status_t fw_app_start_core(fw_app_t *app, const fw_config_t *cfg) {
  fw_app_complete_pending(app);
  (void)fw_app_time(app, app->step); /* the periods so far at the old rate */
  fw_status_t st = fw_init(&app->ctrl, cfg);
  app->last = &app->ctrl.snap; /* fw_init cleared it: the periods so far are gone */
  const fw_config_t *used = fw_get_config(&app->ctrl);
  float f = used != NULL ? used->sensing.f_pwm_Hz : 0.0f;
  app->f_pwm_Hz = (f > 0.0f && f < 4.0e9f) ? (uint32_t)lrintf(f) : 1u;
  app->us_rem %= app->f_pwm_Hz;
  return st;
}

/** Boot from the stored block: configuration and objects (comm_only: the
 *  communication objects alone, for NMT reset communication). Returns true
 *  when it started the core with the stored configuration. */
static bool fw_app_nvm_boot(fw_app_t *app, bool comm_only) {
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

/* ---- CANopen hooks --------------------------------------------------------- */

static co_abort_t fw_app_write_locked(fw_app_t *app, uint16_t index, uint8_t sub, uint32_t v);

static co_abort_t fw_app_on_write(void *ctx, uint16_t index, uint8_t sub, const uint8_t *data,
                                  size_t len) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || data == NULL) {
    return CO_ABORT_GENERAL;
  }
  uint32_t v = co_le_get(data, len > 4u ? 4u : len);
  /* storage is written with the power stage off and outside the lock: a
     flash erase must not hold the control interrupt off */
  if (index == 0x1010u && sub >= 1u) { /* signature checked by the node */
    return fw_app_nvm_save(app);
  }
  if (index == 0x1011u && sub >= 1u) {
    return fw_app_nvm_erase(app);
  }
  uint32_t key = fw_app_lock(app);
  co_abort_t r = fw_app_write_locked(app, index, sub, v);
  fw_app_unlock(app, key);
  return r;
}

static co_abort_t fw_app_write_locked(fw_app_t *app, uint16_t index, uint8_t sub, uint32_t v) {
  if (index == 0x6040u) {
    if (app->cw_pending) {
      (void)fw_controlword(&app->ctrl, app->cw); /* keep every command, in order */
    }
    app->cw = (uint16_t)v;
    app->cw_pending = 1u;
    return CO_ABORT_NONE;
  }
  if (index == 0x2000u) {
    fw_status_t st = fw_set_extractor(&app->ctrl, (fw_extractor_t)v);
    if (st == FW_OK) {
      co_node_set_u32(&app->node, CO_OD_2002_00,
                      v == (uint32_t)FW_EXTRACTOR_SOGI_ADAPTIVE ? 1u : 0u);
    }
    return fw_app_status_abort(st);
  }
  if (index == 0x2002u) {
    fw_extractor_t ex = v != 0u ? FW_EXTRACTOR_SOGI_ADAPTIVE : FW_EXTRACTOR_SOGI;
    fw_status_t st = fw_set_extractor(&app->ctrl, ex);
    if (st == FW_OK) {
      co_node_set_u32(&app->node, CO_OD_2000_00, (uint32_t)ex);
    }
    return fw_app_status_abort(st);
  }
  if (index == 0x2070u && sub == 1u) {
    fw_app_trace_command(app, (uint8_t)v);
    return CO_ABORT_NONE;
  }
  if (index == 0x2080u && sub == 1u) { /* identification: d-axis current reference */
    float x;
    memcpy(&x, &v, sizeof x);
    /* a reference, accepted in the object's whole range (the EDS limits) and clamped
       by the core to +-i_max_A, as the target velocity to the speed limit */
    const fw_status_t st = fw_set_id_ref(&app->ctrl, x);
    return fw_app_status_abort(st == FW_ERR_RANGE ? FW_OK : st);
  }
  const co_od_cfg_link_t *link = fw_app_cfg_link(index, sub);
  if (link != NULL) {
    const fw_config_field_t *f = fw_config_field_find(link->field);
    const co_od_entry_t *e = co_od_entry(link->pos);
    const fw_config_t *cur = fw_get_config(&app->ctrl);
    if (f == NULL || e == NULL || cur == NULL) {
      return CO_ABORT_APP;
    }
    fw_config_t cfg = *cur;
    uint8_t *base = (uint8_t *)&cfg + f->offset;
    if (e->type == CO_TYPE_REAL32) {
      float x;
      memcpy(&x, &v, sizeof x);
      if (f->is_int) {
        return CO_ABORT_APP; /* no such link is generated */
      }
      memcpy(base, &x, sizeof x);
    } else {
      /* integer wire value (signed types sign-extended) -> field / scale */
      bool is_signed = e->type == CO_TYPE_I8 || e->type == CO_TYPE_I16 || e->type == CO_TYPE_I32;
      bool negative = is_signed && e->size >= 1u && e->size <= 4u &&
                      (v & (1u << (8u * e->size - 1u))) != 0u;
      if (negative && e->size < 4u) {
        v |= ~((1u << (8u * e->size)) - 1u); /* sign-extend to 32 bits */
      }
      if (f->is_int) {
        if ((negative && !f->is_signed) || link->scale != 1.0f) {
          return CO_ABORT_VALUE_RANGE; /* a negative value for a uint32_t field */
        }
        /* v holds the value's 32 bits (sign-extended above): int32_t and uint32_t
           fields take them as they are; fw_set_config checks the range */
        memcpy(base, &v, sizeof v);
      } else {
        float w = is_signed ? (float)(int32_t)v : (float)v;
        float x = w / link->scale;
        memcpy(base, &x, sizeof x);
      }
    }
    fw_config_issue_t issue;
    fw_app_complete_pending(app);
    fw_status_t st = fw_set_config(&app->ctrl, &cfg, &issue);
    if (st == FW_OK || st == FW_ERR_SALIENCY) {
      /* FW_ERR_SALIENCY: the core stored the configuration (enabling will
         raise FW_FAULT_SALIENCY_TOO_LOW), so the OD must show it too. The
         other views of the field (SI object / CiA 402 object) follow. */
      fw_app_sync_cfg_to_od(app);
      return CO_ABORT_NONE;
    }
    return fw_app_status_abort(st);
  }
  return CO_ABORT_NONE;
}

/** Power stage off at once for NMT stop / reset communication: CiA 402
 *  "disable voltage" (OPERATION ENABLED, QUICK STOP ACTIVE -> SWITCH ON
 *  DISABLED), applied before this period's fw_step. A controlword received
 *  earlier in the same batch is dropped. A running fault reaction keeps its
 *  bounded braking (0x605E: at most fault_brake_time_s for -1, the default; to
 *  standstill within the ramp's bound for 1 and 2). */
static void fw_app_power_off(fw_app_t *app) {
  app->cw_pending = 0u;
  (void)fw_controlword(&app->ctrl, 0x0000u);
}

/** NMT reset node: the application restarts as after power-up: the
 *  configuration given to fw_app_init, replaced by the stored block when
 *  one is attached and valid (fw_app_attach_nvm). */
static void fw_app_reboot(fw_app_t *app) {
  if (!fw_app_nvm_boot(app, false)) { /* the core starts once, on one configuration */
    (void)fw_app_start_core(app, &app->boot_cfg);
  }
  app->cw_pending = 0u;
  app->mode_applied = -1;
  app->last_fault = 0u; /* a restarted node has nothing to reset: no EMCY */
}

static void fw_app_event_locked(fw_app_t *app, co_event_t ev, uint32_t arg);

static void fw_app_on_event(void *ctx, co_event_t ev, uint32_t arg) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL) {
    return;
  }
  uint32_t key = fw_app_lock(app);
  fw_app_event_locked(app, ev, arg);
  fw_app_unlock(app, key);
}

static void fw_app_event_locked(fw_app_t *app, co_event_t ev, uint32_t arg) {
  switch (ev) {
  case CO_EV_HB_LOST:
    app->count.hb_lost++;
    fw_raise_fault(&app->ctrl, FW_FAULT_HEARTBEAT_LOST);
    break;
  case CO_EV_RPDO_TIMEOUT:
    app->count.rpdo_timeouts++;
    if (fw_state(&app->ctrl) == FW_CIA402_OPERATION_ENABLED) {
      fw_raise_fault(&app->ctrl, FW_FAULT_RPDO_TIMEOUT);
    }
    break;
  case CO_EV_NMT:
    if (arg == (uint32_t)CO_NMT_STOPPED) {
      fw_app_power_off(app);
    }
    break;
  case CO_EV_RESET_NODE:
  case CO_EV_RESET_COMM:
    if (ev == CO_EV_RESET_NODE) {
      fw_app_reboot(app);
      fw_app_ring_discard(app);
    } else {
      fw_app_power_off(app);
      /* the stored communication objects are their power-on values */
      (void)fw_app_nvm_boot(app, true);
    }
    /* the OD went back to its defaults: show the core's real state again */
    fw_app_sync_static_od(app);
    co_node_set_u32(&app->node, CO_OD_1001_00, fw_app_error_register(app->last_fault));
    co_node_set_u32(&app->node, CO_OD_6041_00, fw_statusword(&app->ctrl));
    co_node_set_u32(&app->node, CO_OD_603F_00, (uint32_t)fw_fault_code(&app->ctrl));
    break;
  default:
    break;
  }
}

/* ---- UART ring ------------------------------------------------------------------ */

static bool fw_app_uart_push(fw_app_t *app, const uint8_t *data, size_t len) {
  uint32_t used = app->uart_head - app->uart_tail;
  if ((size_t)(FW_APP_UART_LEN - used) < len) {
    app->count.uart_dropped++;
    return false;
  }
  for (size_t i = 0u; i < len; i++) {
    app->uart[(app->uart_head + i) % FW_APP_UART_LEN] = data[i];
  }
  app->uart_head += (uint32_t)len;
  return true;
}

static void fw_app_send_frame(fw_app_t *app, uint8_t type, const uint8_t *payload, size_t len) {
  uint8_t frame[FW_SERIAL_MAX_ENCODED];
  size_t n = 0u;
  /* the sequence number advances even if the frame is dropped: the
     receiver sees the gap and counts the loss */
  if (fw_serial_link_send(&app->link, type, payload, len, frame, sizeof frame, &n) ==
      FW_SERIAL_OK) {
    (void)fw_app_uart_push(app, frame, n);
  }
}

size_t fw_app_uart_read(fw_app_t *app, uint8_t *buf, size_t cap) {
  if (app == NULL || buf == NULL) {
    return 0u;
  }
  size_t n = 0u;
  while (n < cap && app->uart_tail != app->uart_head) {
    buf[n++] = app->uart[app->uart_tail % FW_APP_UART_LEN];
    app->uart_tail++;
  }
  return n;
}

/* ---- life cycle --------------------------------------------------------------- */

fw_status_t fw_app_init(fw_app_t *app, const fw_config_t *cfg, uint8_t node_id) {
  if (app == NULL || cfg == NULL) {
    return FW_ERR_NULL;
  }
  if (node_id < 1u || node_id > 127u) {
    return FW_ERR_RANGE;
  }
  memset(app, 0, sizeof *app);
  app->mode_applied = -1;
  app->board_kind = (uint8_t)FW_DRIVE_NO_IO; /* until the board says (fw_app_set_board) */
  app->boot_cfg = *cfg;
  fw_status_t st = fw_app_start_core(app, cfg);
  co_callbacks_t cb = {app, fw_app_on_write, fw_app_on_event};
  (void)co_node_init(&app->node, node_id, &cb);
  fw_serial_link_init(&app->link);
  (void)fw_trace_init(&app->trace, app->trace_buf, FW_APP_TRACE_FLOATS);
  fw_app_sync_static_od(app);
  co_node_set_u32(&app->node, CO_OD_6041_00, fw_statusword(&app->ctrl));
  app->init_done = 1u;
  return st;
}

void fw_app_set_board(fw_app_t *app, uint8_t kind, const char *board) {
  if (app == NULL) {
    return;
  }
  app->board_kind = kind;
  app->board_name = board;
  co_node_set_u32(&app->node, CO_OD_2090_01, kind);
  co_node_set_str(&app->node, CO_OD_2090_02, board != NULL ? board : "");
}

FW_ISR_OPT void fw_app_ref_sample(fw_app_t *app, uint8_t status, int32_t count) {
  app->ref_status_in = status;
  app->ref_count_in = count;
}

bool fw_app_can_rx(fw_app_t *app, const fw_can_frame_t *frame) {
  if (app == NULL || frame == NULL) {
    return false;
  }
  return co_node_rx_isr(&app->node, frame) == CO_OK;
}

bool fw_app_can_tx_pop(fw_app_t *app, fw_can_frame_t *frame) {
  if (app == NULL || frame == NULL) {
    return false;
  }
  return co_node_tx_pop(&app->node, frame);
}

void fw_app_snapshot(const void *app, fw_snapshot_t *snap) {
  const fw_app_t *a = (const fw_app_t *)app;
  if (a == NULL || snap == NULL) {
    return;
  }
  fw_get_snapshot_of(&a->ctrl, a->last, snap);
}

size_t fw_app_sizeof(void) { return sizeof(fw_app_t); }

fw_ctrl_t *fw_app_ctrl(fw_app_t *app) { return app != NULL ? &app->ctrl : NULL; }
co_node_t *fw_app_node(fw_app_t *app) { return app != NULL ? &app->node : NULL; }
const fw_app_counters_t *fw_app_counters(const fw_app_t *app) {
  return app != NULL ? &app->count : NULL;
}

/* ---- step ---------------------------------------------------------------------- */

static void fw_app_apply_commands(fw_app_t *app) {
  co_node_t *n = &app->node;
  const fw_config_t *cfg = fw_get_config(&app->ctrl);
  uint32_t key = fw_app_lock(app);
  if (app->cw_pending) {
    app->cw_pending = 0u;
    (void)fw_controlword(&app->ctrl, app->cw);
  }
  int32_t mode = CO_NODE_GET_I(n, 6060_00);
  fw_mode_t m = mode == FW_APP_MODE_CST ? FW_MODE_FORCE : FW_MODE_SPEED;
  if (app->mode_applied != (int32_t)m && fw_set_mode(&app->ctrl, m) == FW_OK) {
    app->mode_applied = (int32_t)m;
  }
  if (cfg != NULL) {
    float v_mps = (float)CO_NODE_GET_I(n, 60FF_00) * 1.0e-6f;
    (void)fw_set_speed_ref(&app->ctrl, fw_units_mps_to_radps_e(cfg, v_mps));
    float t_pm = (float)CO_NODE_GET_I(n, 6071_00);
    (void)fw_set_iq_ref(&app->ctrl, t_pm * 1.0e-3f * cfg->loops.i_max_A);
  }
  /* a fault reset does not clear a heartbeat that is still missing, nor an
     RPDO deadline that is still missed (once enabled again) */
  if (fw_fault_code(&app->ctrl) == FW_FAULT_NONE) {
    for (uint32_t k = 0u; k < CO_HB_CONSUMERS; k++) {
      if (app->node.hb[k].lost) {
        fw_raise_fault(&app->ctrl, FW_FAULT_HEARTBEAT_LOST);
        break;
      }
    }
  }
  if (fw_fault_code(&app->ctrl) == FW_FAULT_NONE &&
      fw_state(&app->ctrl) == FW_CIA402_OPERATION_ENABLED) {
    for (uint32_t k = 0u; k < CO_OD_NR_RPDO; k++) {
      if (app->node.rpdo[k].timed_out) {
        fw_raise_fault(&app->ctrl, FW_FAULT_RPDO_TIMEOUT);
        break;
      }
    }
  }
  fw_app_unlock(app, key);
}

/* The OD entries the background writes or reads every period are addressed by
 * their generated compile-time handles (co_node.h CO_NODE_PUT/GET): the same
 * bytes as co_node_set_* / co_node_get_*, without a lookup or a check. Runs of
 * entries indexed by a counter rely on their subs lying back to back: */
_Static_assert(CO_OD_OFF_2030_08 == CO_OD_OFF_2030_01 + 7u * CO_OD_LEN_2030_01,
               "0x2030:1..8 contiguous");
_Static_assert(CO_OD_LEN_2060_03 == 1u && CO_OD_OFF_2060_0A == CO_OD_OFF_2060_03 + 7u,
               "0x2060:3..10 contiguous bytes");

static void fw_app_update_od(fw_app_t *app, const fw_app_period_t *p) {
  const fw_snapshot_t *s = &p->snap;
  co_node_t *n = &app->node;
  const fw_config_t *cfg = fw_get_config(&app->ctrl);
  float i_max = (cfg != NULL && cfg->loops.i_max_A > 0.0f) ? cfg->loops.i_max_A : 1.0f;
  CO_NODE_PUT(n, 6041_00, s->statusword);
  CO_NODE_PUT(n, 6061_00, s->mode == (uint8_t)FW_MODE_FORCE ? FW_APP_MODE_CST : FW_APP_MODE_CSV);
  CO_NODE_PUT(n, 6064_00, fw_app_round_i32(s->pos_hat_m * 1.0e6f));
  CO_NODE_PUT(n, 606C_00, fw_app_round_i32(s->speed_hat_mps * 1.0e6f));
  CO_NODE_PUT(n, 6077_00, fw_app_sat_i16(s->i_dq_A[1] / i_max * 1000.0f));
  CO_NODE_PUT(n, 603F_00, s->fault_code);
  CO_NODE_PUT_F32(n, 2020_01, s->theta_hat_rad);
  CO_NODE_PUT_F32(n, 2020_02, s->omega_hat_radps);
  CO_NODE_PUT_F32(n, 2020_03, s->speed_hat_mps);
  CO_NODE_PUT_F32(n, 2020_04, s->pll_err_rad);
  CO_NODE_PUT_F32(n, 2020_05, s->hf_amp_A);
  CO_NODE_PUT_F32(n, 2020_06, s->pll_err_f_rad);
  CO_NODE_PUT_F32(n, 2020_07, s->sogi_k_eff);
  CO_NODE_PUT(n, 2020_08, s->start_phase);
  CO_NODE_PUT_F32(n, 2020_09, s->accel_dist_radps2);
  CO_NODE_PUT(n, 2090_03, p->step);
  CO_NODE_PUT(n, 2091_01, p->ref_status);
  CO_NODE_PUT(n, 2091_04, p->ref_status == (uint8_t)FW_REF_OK ? p->ref_count : INT32_MIN);
  CO_NODE_PUT_F32(n, 2091_05, s->ref_pos_m);
  CO_NODE_PUT(n, 2091_06, app->ref_faults);
  uint16_t hist[FW_FAULT_HISTORY_LEN];
  uint32_t nh = fw_fault_history(&app->ctrl, hist, FW_FAULT_HISTORY_LEN);
  for (uint32_t k = 0u; k < 8u; k++) {
    co_node_put_at(n, (uint16_t)(CO_OD_OFF_2030_01 + k * CO_OD_LEN_2030_01), CO_OD_LEN_2030_01,
                   k < nh ? hist[k] : 0u);
  }
  CO_NODE_PUT(n, 2070_02, (uint32_t)app->trace.state);
  CO_NODE_PUT_F32(n, 2080_02, s->L_small_meas_H);
  CO_NODE_PUT_F32(n, 2080_03, s->L_large_meas_H);
  if (s->cia402_state != (uint8_t)FW_CIA402_OPERATION_ENABLED &&
      CO_NODE_GET_F32(n, 2080_01) != 0.0f) {
    /* an identification's d-axis current never survives leaving OPERATION ENABLED */
    CO_NODE_PUT_F32(n, 2080_01, 0.0f);
    uint32_t key = fw_app_lock(app);
    (void)fw_set_id_ref(&app->ctrl, 0.0f);
    fw_app_unlock(app, key);
  }
}

static void fw_app_faults(fw_app_t *app, const fw_snapshot_t *s) {
  uint16_t code = s->fault_code;
  if (code == app->last_fault) {
    return;
  }
  uint8_t reg = fw_app_error_register(code);
  uint8_t msef[5] = {s->cia402_state, (uint8_t)s->step_count, (uint8_t)(s->step_count >> 8),
                     (uint8_t)(s->step_count >> 16), (uint8_t)(s->step_count >> 24)};
  /* a new fault, or 0x0000 "error reset / no error" when it was cleared */
  if (co_node_emcy(&app->node, code, reg, msef) == CO_OK) {
    app->count.emcy++;
  }
  app->last_fault = code;
}

static void fw_app_serial(fw_app_t *app, const fw_snapshot_t *s, uint32_t step) {
  co_node_t *n = &app->node;
  /* the telemetry configuration (0x2060) read in place: as cheap as a cached
     copy, and an SDO write is seen at the next period without a hook */
  uint32_t dec = CO_NODE_GET(n, 2060_01);
  if (dec > 0u && step % dec == 0u) {
    uint8_t cnt = (uint8_t)CO_NODE_GET(n, 2060_02);
    uint8_t payload[FW_SERIAL_MAX_PAYLOAD];
    if (cnt > FW_SERIAL_MAX_SIGNALS) {
      cnt = FW_SERIAL_MAX_SIGNALS;
    }
    size_t len = fw_serial_telemetry_payload(s, &n->od[CO_OD_OFF_2060_03], cnt, payload,
                                             sizeof payload);
    if (len > 0u) {
      fw_app_send_frame(app, FW_SERIAL_TYPE_TELEMETRY, payload, len);
      app->count.telemetry_sent++;
    }
  }
  fw_trace_sample(&app->trace, s, s->fault_code != 0u);
  if (app->trace.state == FW_TRACE_UPLOADING) {
    /* one upload frame per control period, when the UART has room */
    uint32_t used = app->uart_head - app->uart_tail;
    if (FW_APP_UART_LEN - used >= FW_SERIAL_MAX_ENCODED) {
      uint8_t type = 0u;
      uint8_t payload[FW_SERIAL_MAX_PAYLOAD];
      size_t len = 0u;
      if (fw_trace_upload_next(&app->trace, &type, payload, sizeof payload, &len)) {
        fw_app_send_frame(app, type, payload, len);
      }
    }
  }
}

/* ---- the control and supervision interrupts ---------------------------------- */

/* Before the step: the slot of this period (NULL when the ring is full: the
 * background is behind), into whose snapshot the core writes the period's
 * fields (fw_step_into); the acquire orders the background's last reads of
 * that slot before these writes. */
FW_ISR_OPT static inline fw_app_period_t *fw_app_slot(fw_app_t *app, uint32_t head) {
  uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_acquire);
  return FW_LIKELY(head - tail < FW_APP_SNAP_RING) ? &app->ring[head % FW_APP_SNAP_RING] : NULL;
}

/* After the supervision: complete the period's raw half in its slot p (the
 * blocks' states; the background completes the rest) and publish it to the
 * background. dst is where the step wrote (p's snapshot, or ctrl.snap when
 * the ring is full); the groups it did not write are the period before's.
 * One release fence for the slot and the head. */
FW_ISR_OPT static void fw_app_publish(fw_app_t *app, const fw_app_sup_t *sp) {
  fw_app_period_t *p = sp->p;
  fw_snapshot_t *dst = sp->dst;
  if (FW_UNLIKELY(sp->written != FW_SNAP_W_ALL)) {
    fw_snapshot_carry(dst, app->last, sp->written);
  }
  app->last = dst;
  if (FW_LIKELY(p != NULL)) {
    fw_snapshot_capture_state(&app->ctrl, &p->snap, &p->raw);
    /* the fields that change only at start-up events and on commands: when
       they changed since this slot last had them (the slot keeps its copy) */
    const uint32_t gen = fw_snapshot_slow_gen(&app->ctrl);
    if (FW_UNLIKELY(p->slow_gen != gen)) {
      fw_snapshot_capture_slow(&app->ctrl, &p->snap);
      p->slow_gen = gen;
    }
    p->step = sp->step; /* p->done is then not step + 1: not completed */
  } else {
    app->count.snap_overruns++; /* the background is behind: it never sees this period */
  }
  atomic_thread_fence(memory_order_release);
  atomic_store_explicit(&app->ring_head, FW_LIKELY(p != NULL) ? sp->head + 1u : sp->head,
                        memory_order_relaxed);
}

/* The supervision half: the core's supervision of the period the control
 * half handed over, then its publication. */
FW_ISR_OPT static FW_ALWAYS_INLINE bool fw_app_sup(fw_app_t *app, fw_outputs_t *out) {
  if (FW_UNLIKELY(atomic_load_explicit(&app->sup_pending, memory_order_acquire) == 0u)) {
    return false; /* nothing handed over */
  }
  atomic_store_explicit(&app->sup_busy, 1u, memory_order_relaxed);
  const bool off = fw_supervise(&app->ctrl, out, app->sup.dst);
  fw_app_publish(app, &app->sup);
  atomic_store_explicit(&app->sup_pending, 0u, memory_order_release);
  atomic_store_explicit(&app->sup_busy, 0u, memory_order_relaxed);
  return off;
}

/* The control interrupt found the last period's supervision not finished: the
 * timing is broken (the supervision interrupt starved, or a port that never
 * pends it), a hard fault (FW_FAULT_SUPERVISION_MISSED), and counted. Not
 * started: the late supervision runs here, so the period is judged and
 * published (a broken port still shows its fault on the bus). Started and
 * preempted by this interrupt: it is left to finish; the caller does not
 * hand this period over (true). */
static FW_NOINLINE bool fw_app_late(fw_app_t *app) {
  app->count.sup_missed++;
  const bool preempted = atomic_load_explicit(&app->sup_busy, memory_order_relaxed) != 0u;
  if (!preempted) {
    fw_outputs_t off;
    (void)fw_app_sup(app, &off); /* the duties of that period are long applied */
  }
  fw_raise_fault(&app->ctrl, FW_FAULT_SUPERVISION_MISSED);
  return preempted;
}

/* The control half of one period (the control interrupt's, or fw_app_step's):
 * the core steps into this period's slot (ctrl.snap when the ring is full)
 * from the ADC counts or, adc NULL, the physical inputs; the period is
 * counted (the time base) and handed to the supervision (fw_app_late when the
 * last one has not finished). */
FW_ISR_OPT static FW_ALWAYS_INLINE void fw_app_control(fw_app_t *app, const fw_inputs_t *in,
                                                       const fw_adc_inputs_t *adc,
                                                       fw_outputs_t *out) {
  const uint32_t step = app->step;
  bool preempted = false;
  if (FW_UNLIKELY(atomic_load_explicit(&app->sup_pending, memory_order_relaxed) != 0u)) {
    preempted = fw_app_late(app);
  }
  const uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_relaxed);
  fw_app_period_t *p = FW_LIKELY(!preempted) ? fw_app_slot(app, head) : NULL;
  fw_snapshot_t *dst = FW_LIKELY(p != NULL) ? &p->snap : &app->ctrl.snap;
  const unsigned written = fw_step_into(&app->ctrl, in, adc, out, dst);
  if (FW_LIKELY(p != NULL)) { /* the reference sensor's reading of this period, as sampled */
    p->ref_count = app->ref_count_in;
    p->ref_status = app->ref_status_in;
  }
  if (FW_LIKELY(!preempted)) {
    fw_app_sup_t *sp = &app->sup;
    sp->p = p;
    sp->dst = dst;
    sp->written = written;
    sp->head = head;
    sp->step = step;
    atomic_store_explicit(&app->sup_pending, 1u, memory_order_release);
  }
  app->step = step + 1u;
  atomic_store_explicit(&app->isr_step, step + 1u, memory_order_release);
}

FW_ISR_OPT void fw_app_isr(void *ctx, const fw_adc_inputs_t *adc, fw_outputs_t *out) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || adc == NULL || out == NULL) {
    if (out != NULL) {
      memset(out, 0, sizeof *out);
    }
    return;
  }
  fw_app_control(app, NULL, adc, out); /* the core's one ADC conversion and range check */
}

FW_ISR_OPT bool fw_app_supervise(void *ctx, fw_outputs_t *out) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || out == NULL) {
    return false;
  }
  return fw_app_sup(app, out);
}

/* ---- the background loop ------------------------------------------------------- */

/* Input half: frames in, commands to the core. */
static void fw_app_bg_input(fw_app_t *app, uint32_t now) {
  co_node_process_rx(&app->node, now);
  fw_app_apply_commands(app);
}

/* Output half: every published period in order, the OD, frames out. The
 * newest period's slot is released only after the OD was written from it. */
static void fw_app_bg_output(fw_app_t *app, uint32_t now) {
  uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_relaxed);
  uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_acquire);
  while (tail != head) {
    fw_app_period_t *p = &app->ring[tail % FW_APP_SNAP_RING];
    fw_app_complete(app, p);
    if (p->ref_status == (uint8_t)FW_REF_FAULT || p->ref_status == (uint8_t)FW_REF_NOT_REFERENCED) {
      app->ref_faults++;
    }
    fw_app_faults(app, &p->snap);
    fw_app_serial(app, &p->snap, p->step);
    if (tail + 1u == head) {
      fw_app_update_od(app, p);
    }
    tail++;
    atomic_store_explicit(&app->ring_tail, tail, memory_order_release);
  }
  co_node_process_tx(&app->node, now);
}

void fw_app_background(void *ctx) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL) {
    return;
  }
  uint32_t now = fw_app_time(app, atomic_load_explicit(&app->isr_step, memory_order_acquire));
  fw_app_bg_input(app, now);
  fw_app_bg_output(app, now);
}

void fw_app_step(void *ctx, const fw_inputs_t *in, fw_outputs_t *out) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || in == NULL || out == NULL) {
    if (out != NULL) {
      memset(out, 0, sizeof *out);
    }
    return;
  }
  uint32_t now = fw_app_time(app, app->step);
  fw_app_bg_input(app, now);
  fw_app_control(app, in, NULL, out);
  (void)fw_app_sup(app, out);
  fw_app_bg_output(app, now);
}
