/**
 * @file fw_app_od.c
 * @brief The drive application's object dictionary side: the wire's rounding
 *        and error register, the OD's sync with the core's configuration, the
 *        hooked objects' handlers (od.yaml hook:; 0x1010/0x1011 are fw_nvm.c's,
 *        0x2070:1 fw_trace.c's), the configuration objects' writes, the
 *        objects a published period updates and the EMCY of a fault change.
 */
#include <float.h>
#include <math.h>
#include <string.h>

#include "fw_app_hooks.h"
#include "fw_app_internal.h"
#include "pmlsm/fw_app.h"

#ifndef PMLSM_BUILD_ID
#define PMLSM_BUILD_ID "dev"
#endif

/* ---- wire values ------------------------------------------------------------ */

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

/* ---- configuration and static objects --------------------------------------- */

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

void fw_app_sync_static_od(fw_app_t *app) {
  /* CiA 301 0x1010/0x1011 read: bit 0 = saves / restores on command */
  co_node_set_u32(&app->node, CO_OD_1010_01, app->nvm_supported ? 1u : 0u);
  co_node_set_u32(&app->node, CO_OD_1011_01, app->nvm_supported ? 1u : 0u);
  co_node_set_u32(&app->node, CO_OD_2040_00, FW_VERSION_U32);
  co_node_set_str(&app->node, CO_OD_2041_00, PMLSM_BUILD_ID);
  co_node_set_u32(&app->node, CO_OD_2090_01, app->board_kind);
  co_node_set_str(&app->node, CO_OD_2090_02, app->board_name != NULL ? app->board_name : "");
  fw_app_sync_cfg_to_od(app);
}

co_abort_t fw_app_status_abort(fw_status_t st) {
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

/* ---- hooked objects and configuration objects -------------------------------- */

/* The hooked objects' handlers (od.yaml hook:, the generated fw_app_hooks.h);
 * those of 0x1010 / 0x1011 are fw_nvm.c's, that of 0x2070:1 fw_trace.c's. */

co_abort_t fw_app_hook_controlword(fw_app_t *app, uint32_t v) {
  if (app->cw_pending) {
    (void)fw_controlword(&app->ctrl, app->cw); /* keep every command, in order */
  }
  app->cw = (uint16_t)v;
  app->cw_pending = 1u;
  return CO_ABORT_NONE;
}

co_abort_t fw_app_hook_extractor(fw_app_t *app, uint32_t v) {
  fw_status_t st = fw_set_extractor(&app->ctrl, (fw_extractor_t)v);
  if (st == FW_OK) {
    co_node_set_u32(&app->node, CO_OD_2002_00,
                    v == (uint32_t)FW_EXTRACTOR_SOGI_ADAPTIVE ? 1u : 0u);
  }
  return fw_app_status_abort(st);
}

co_abort_t fw_app_hook_adaptive_sogi(fw_app_t *app, uint32_t v) {
  fw_extractor_t ex = v != 0u ? FW_EXTRACTOR_SOGI_ADAPTIVE : FW_EXTRACTOR_SOGI;
  fw_status_t st = fw_set_extractor(&app->ctrl, ex);
  if (st == FW_OK) {
    co_node_set_u32(&app->node, CO_OD_2000_00, (uint32_t)ex);
  }
  return fw_app_status_abort(st);
}

co_abort_t fw_app_hook_id_ref(fw_app_t *app, uint32_t v) { /* identification: i_d reference */
  float x;
  memcpy(&x, &v, sizeof x);
  /* a reference, accepted in the object's whole range (the EDS limits) and clamped
     by the core to +-i_max_A, as the target velocity to the speed limit */
  const fw_status_t st = fw_set_id_ref(&app->ctrl, x);
  return fw_app_status_abort(st == FW_ERR_RANGE ? FW_OK : st);
}

/** A write of an object that shows a fw_config_t field (co_od_cfg_links): the
 *  core's configuration with the field changed (fw_set_config), the field's other
 *  views in the OD following. Other objects: nothing to do. */
co_abort_t fw_app_write_config(fw_app_t *app, uint16_t index, uint8_t sub, uint32_t v) {
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

/* ---- a published period's objects, EMCY ------------------------------------- */

/* The OD entries the background writes or reads every period are addressed by
 * their generated compile-time handles (co_node.h CO_NODE_PUT/GET): the same
 * bytes as co_node_set_* / co_node_get_*, without a lookup or a check. Runs of
 * entries indexed by a counter rely on their subs lying back to back: */
_Static_assert(CO_OD_OFF_2030_08 == CO_OD_OFF_2030_01 + 7u * CO_OD_LEN_2030_01,
               "0x2030:1..8 contiguous");
_Static_assert(CO_OD_LEN_2060_03 == 1u && CO_OD_OFF_2060_0A == CO_OD_OFF_2060_03 + 7u,
               "0x2060:3..10 contiguous bytes");

void fw_app_update_od(fw_app_t *app, const fw_app_period_t *p) {
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
  /* the current zeros measured at boot (written once by the control interrupt,
   * at the calibration's end; the nominal zero before) */
  CO_NODE_PUT_F32(n, 2056_05, fw_current_zero_counts(&app->ctrl, 0u));
  CO_NODE_PUT_F32(n, 2056_06, fw_current_zero_counts(&app->ctrl, 1u));
  CO_NODE_PUT_F32(n, 2056_07, fw_current_zero_counts(&app->ctrl, 2u));
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

void fw_app_emcy(fw_app_t *app, const fw_snapshot_t *s) {
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
