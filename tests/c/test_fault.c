/* Tests for fw_fault: latch order (first cause reported), history (newest
 * first, repeats once, depth FW_FAULT_HISTORY_LEN), hard/braking reaction,
 * reset, input checks and their priority, and the protections against
 * hand-computed thresholds (i2t trip time, overspeed, position limits with
 * the drive-back rule, following-error time). */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_config.h"
#include "pmlsm/fw_fault.h"
#include "tinytest.h"

static void test_latch_first_cause_and_history(void) {
  fw_fault_latch_t f;
  fw_fault_latch_init(&f);
  const int32_t ramp = (int32_t)FW_REACT_RAMP;
  TT_CHECK(fw_fault_latch_code(&f) == FW_FAULT_NONE);
  fw_fault_latch_update(&f, FW_FAULT_NONE, ramp); /* ignored */
  TT_CHECK(f.hist_count == 0u);
  fw_fault_latch_update(&f, FW_FAULT_HEARTBEAT_LOST, ramp);
  TT_CHECK(fw_fault_latch_code(&f) == FW_FAULT_HEARTBEAT_LOST);
  TT_CHECK(f.hard == 0u); /* heartbeat: brakes first */
  fw_fault_latch_update(&f, FW_FAULT_HEARTBEAT_LOST, ramp); /* repeat: once */
  fw_fault_latch_update(&f, FW_FAULT_OVERCURRENT, ramp);
  TT_CHECK(fw_fault_latch_code(&f) == FW_FAULT_HEARTBEAT_LOST); /* first cause stays */
  TT_CHECK(f.hard == 1u);                                       /* overcurrent: hard */
  uint16_t h[FW_FAULT_HISTORY_LEN + 2u];
  TT_CHECK(fw_fault_latch_history(&f, h, FW_FAULT_HISTORY_LEN) == 2u);
  TT_CHECK(h[0] == (uint16_t)FW_FAULT_OVERCURRENT && h[1] == (uint16_t)FW_FAULT_HEARTBEAT_LOST);
  TT_CHECK(fw_fault_latch_history(&f, h, 1u) == 1u && h[0] == (uint16_t)FW_FAULT_OVERCURRENT);
  /* reset: cause and hard flag gone, history kept */
  fw_fault_latch_reset(&f);
  TT_CHECK(fw_fault_latch_code(&f) == FW_FAULT_NONE && f.hard == 0u && f.hist_count == 2u);
  /* depth: ten alternating causes keep the newest eight, newest first */
  const fw_fault_t a = FW_FAULT_I2T, b = FW_FAULT_OVERSPEED;
  for (int i = 0; i < 10; i++) {
    fw_fault_latch_update(&f, (i % 2) ? b : a, ramp);
  }
  TT_CHECK(fw_fault_latch_history(&f, h, FW_FAULT_HISTORY_LEN + 2u) == FW_FAULT_HISTORY_LEN);
  for (uint32_t i = 0; i < FW_FAULT_HISTORY_LEN; i++) {
    TT_CHECK(h[i] == (uint16_t)((i % 2u) ? a : b)); /* the 10th (b) is newest */
  }
  TT_CHECK(fw_fault_latch_code(&f) == a); /* first after the reset */
}

static void test_reaction(void) {
  const int32_t off = (int32_t)FW_REACT_SWITCH_OFF;
  /* every braking code (CiA 402 1, 2 and the manufacturer-specific -1) brakes first
     for the faults that leave the estimate trustworthy, and only for those */
  const int32_t braking[] = {(int32_t)FW_REACT_RAMP, (int32_t)FW_REACT_QUICK_RAMP,
                             (int32_t)FW_REACT_BRAKE_TIMED};
  for (size_t i = 0; i < sizeof braking / sizeof braking[0]; i++) {
    TT_CHECK(fw_fault_brakes_first(braking[i], FW_FAULT_HEARTBEAT_LOST));
    TT_CHECK(fw_fault_brakes_first(braking[i], FW_FAULT_POSITION_LIMIT));
    TT_CHECK(fw_fault_brakes_first(braking[i], FW_FAULT_I2T));
    TT_CHECK(!fw_fault_brakes_first(braking[i], FW_FAULT_EST_PLL_ERROR));
    TT_CHECK(!fw_fault_brakes_first(braking[i], FW_FAULT_EST_BEMF_MISMATCH));
    TT_CHECK(!fw_fault_brakes_first(braking[i], FW_FAULT_OVERCURRENT));
  }
  TT_CHECK(!fw_fault_brakes_first(off, FW_FAULT_HEARTBEAT_LOST));
  TT_CHECK(FW_REACT_BRAKE_TIMED < 0); /* manufacturer-specific: negative (CiA 402) */
  fw_fault_latch_t f;
  fw_fault_latch_init(&f);
  fw_fault_latch_update(&f, FW_FAULT_HEARTBEAT_LOST, off);
  TT_CHECK(f.hard == 1u);
}

/* How long each reaction may brake: -1 the configured time at any speed; the
 * CiA 402 ramps the time the current limit needs to stop the configured mass
 * (computed here in double from the paper motor's numbers: K_F = 1.5 (pi / tau)
 * psi_f) plus the margin, so they reach standstill first; 0 none. */
static void test_brake_time_bound(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  const double k_f = 1.5 * M_PI / 0.024 * 0.1827;    /* N/A, 35.87 */
  const double a = k_f * 20.0 / 32.13;               /* m/s^2 at i_max 20 A, 32.13 kg */
  TT_CHECK_NEAR(a, 22.33, 0.01);
  const float speeds[] = {0.0f, 0.5f, -1.0f, 2.0f, 3.6f};
  for (size_t i = 0; i < sizeof speeds / sizeof speeds[0]; i++) {
    const double v = fabs((double)speeds[i]);
    TT_CHECK_NEAR(fw_fault_brake_time_max_s(&cfg, FW_REACT_BRAKE_TIMED, speeds[i]), 0.08, 1e-7);
    TT_CHECK_NEAR(fw_fault_brake_time_max_s(&cfg, FW_REACT_RAMP, speeds[i]), v / a + 0.5, 1e-5);
    TT_CHECK_NEAR(fw_fault_brake_time_max_s(&cfg, FW_REACT_QUICK_RAMP, speeds[i]), v / a + 0.5,
                  1e-5);
    TT_CHECK(fw_fault_brake_time_max_s(&cfg, FW_REACT_SWITCH_OFF, speeds[i]) == 0.0f);
    TT_CHECK(fw_fault_brake_time_max_s(&cfg, 7, speeds[i]) == 0.0f); /* not a code */
  }
  /* a heavier axis takes longer, a stronger current limit less */
  fw_config_t heavy = cfg;
  heavy.machine.mass_kg = 4.0f * cfg.machine.mass_kg;
  TT_CHECK_NEAR(fw_fault_brake_time_max_s(&heavy, FW_REACT_QUICK_RAMP, 2.0f),
                2.0 / (a / 4.0) + 0.5, 1e-4);
  /* the margin is quick_stop_time_s; a NaN speed leaves the margin alone */
  cfg.protection.quick_stop_time_s = 0.1f;
  TT_CHECK_NEAR(fw_fault_brake_time_max_s(&cfg, FW_REACT_RAMP, 1.0f), 1.0 / a + 0.1, 1e-5);
  TT_CHECK_NEAR(fw_fault_brake_time_max_s(&cfg, FW_REACT_RAMP, NAN), 0.1, 1e-7);
}

static void test_inputs(void) {
  fw_config_t cfg;
  fw_config_default(&cfg); /* i_trip 24 A, u_dc 150..420 V */
  fw_inputs_t in = {{1.0f, -0.5f, -0.5f}, 300.0f};
  TT_CHECK(fw_fault_check_inputs(&cfg.protection, &in, true) == FW_FAULT_NONE);
  in.i_abc_A[1] = -24.5f;
  TT_CHECK(fw_fault_check_inputs(&cfg.protection, &in, true) == FW_FAULT_OVERCURRENT);
  in.i_abc_A[2] = NAN; /* invalid input outranks overcurrent */
  TT_CHECK(fw_fault_check_inputs(&cfg.protection, &in, true) == FW_FAULT_INPUT_INVALID);
  in.i_abc_A[1] = in.i_abc_A[2] = 0.0f;
  in.u_dc_V = INFINITY;
  TT_CHECK(fw_fault_check_inputs(&cfg.protection, &in, false) == FW_FAULT_INPUT_INVALID);
  in.u_dc_V = 421.0f;
  TT_CHECK(fw_fault_check_inputs(&cfg.protection, &in, false) == FW_FAULT_DC_OVERVOLTAGE);
  in.u_dc_V = 100.0f; /* undervoltage only matters with the power stage on */
  TT_CHECK(fw_fault_check_inputs(&cfg.protection, &in, false) == FW_FAULT_NONE);
  TT_CHECK(fw_fault_check_inputs(&cfg.protection, &in, true) == FW_FAULT_DC_UNDERVOLTAGE);
}

static fw_protect_in_t quiet_in(void) {
  fw_protect_in_t in;
  memset(&in, 0, sizeof(in));
  in.speed_mode = 1u;
  return in;
}

static void test_i2t(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  cfg.protection.i_rated_A = 10.0f;
  cfg.loops.i_max_A = 20.0f;
  cfg.protection.i2t_time_s = 0.1f;
  const float dt = 1.0f / 24000.0f;
  fw_protect_t p;
  fw_protect_init(&p, &cfg, dt);
  /* at i_max from cold: (i_max^2 - i_r^2) t > (i_max^2 - i_r^2) i2t_time after i2t_time */
  fw_protect_in_t in = quiet_in();
  in.i_dq_A[0] = 12.0f; /* |i| = 20 A */
  in.i_dq_A[1] = 16.0f;
  int k_trip = -1;
  for (int k = 1; k <= 3000 && k_trip < 0; k++) {
    if (fw_protect_update(&p, &cfg, &in) == FW_FAULT_I2T) {
      k_trip = k;
    }
  }
  TT_CHECK(k_trip >= 2399 && k_trip <= 2402); /* 0.1 s = 2400 periods */
  /* power off: cools at i_r^2 per second, floor 0 */
  const float before = p.i2t_A2s;
  fw_protect_cool(&p, &cfg);
  TT_CHECK_NEAR(p.i2t_A2s, before - 100.0f * dt, 1e-5);
  for (int k = 0; k < 24000; k++) {
    fw_protect_cool(&p, &cfg);
  }
  TT_CHECK(p.i2t_A2s == 0.0f);
  /* i_rated >= i_max: off */
  cfg.protection.i_rated_A = cfg.loops.i_max_A;
  fw_protect_init(&p, &cfg, dt);
  int n_trip = 0;
  for (int k = 0; k < 30000; k++) {
    n_trip += fw_protect_update(&p, &cfg, &in) == FW_FAULT_I2T;
  }
  TT_CHECK(n_trip == 0);
}

static void test_speed_position_follow(void) {
  fw_config_t cfg;
  fw_config_default(&cfg); /* tau 0.024 m, v_max 3 m/s, follow 0.5 m/s for 0.5 s */
  cfg.protection.pos_limit_min_m = -0.5f;
  cfg.protection.pos_limit_max_m = 0.5f;
  const float dt = 1.0f / 24000.0f;
  fw_protect_t p;
  fw_protect_init(&p, &cfg, dt);
  /* OVERSPEED at v_max_mps x overspeed_margin (1.2): pi 3.6 / tau */
  const float w_trip = (float)(M_PI * 3.0 * 1.2 / 0.024);
  TT_CHECK_NEAR(p.w_trip_radps, w_trip, 1e-3);
  fw_protect_in_t in = quiet_in();
  in.omega_hat_radps = 1.001f * w_trip;
  TT_CHECK(fw_protect_update(&p, &cfg, &in) == FW_FAULT_OVERSPEED);
  in.omega_hat_radps = -1.001f * w_trip;
  TT_CHECK(fw_protect_update(&p, &cfg, &in) == FW_FAULT_OVERSPEED);
  in.omega_hat_radps = -0.999f * w_trip; /* above v_max_mps itself: the margin */
  TT_CHECK(fw_protect_update(&p, &cfg, &in) == FW_FAULT_NONE);
  /* margin 1.0: at v_max_mps itself */
  fw_config_t tight = cfg;
  tight.protection.overspeed_margin = 1.0f;
  fw_protect_t pt;
  fw_protect_init(&pt, &tight, dt);
  const float w_vmax = (float)(M_PI * 3.0 / 0.024);
  in.omega_hat_radps = 1.001f * w_vmax;
  TT_CHECK(fw_protect_update(&pt, &tight, &in) == FW_FAULT_OVERSPEED);
  in.omega_hat_radps = 0.999f * w_vmax;
  TT_CHECK(fw_protect_update(&pt, &tight, &in) == FW_FAULT_NONE);
  /* beyond the upper limit: trips while the command points out or is zero */
  in.pos_m = 0.51f;
  in.cmd = 1.0f;
  TT_CHECK(fw_protect_update(&p, &cfg, &in) == FW_FAULT_POSITION_LIMIT);
  in.cmd = 0.0f;
  TT_CHECK(fw_protect_update(&p, &cfg, &in) == FW_FAULT_POSITION_LIMIT);
  in.cmd = -1.0f; /* driving back: allowed */
  TT_CHECK(fw_protect_update(&p, &cfg, &in) == FW_FAULT_NONE);
  in.pos_m = -0.51f;
  TT_CHECK(fw_protect_update(&p, &cfg, &in) == FW_FAULT_POSITION_LIMIT);
  in.pos_m = 0.0f;
  /* following error: |ref - w_f| > pi 0.5 / tau for more than 0.5 s */
  const float w_follow = (float)(M_PI * 0.5 / 0.024);
  in.speed_ref_radps_e = 1.01f * w_follow;
  in.omega_f_radps = 0.0f;
  int k_trip = -1;
  for (int k = 1; k <= 13000 && k_trip < 0; k++) {
    if (fw_protect_update(&p, &cfg, &in) == FW_FAULT_FOLLOWING_ERROR) {
      k_trip = k;
    }
  }
  TT_CHECK(k_trip >= 11999 && k_trip <= 12002); /* 0.5 s = 12000 periods */
  fw_protect_reset(&p);
  in.quick_stop = 1u; /* braking: not supervised */
  int n_fault = 0;
  for (int k = 0; k < 13000; k++) {
    n_fault += fw_protect_update(&p, &cfg, &in) != FW_FAULT_NONE;
  }
  in.quick_stop = 0u;
  in.speed_mode = 0u; /* FORCE mode: not supervised */
  for (int k = 0; k < 13000; k++) {
    n_fault += fw_protect_update(&p, &cfg, &in) != FW_FAULT_NONE;
  }
  TT_CHECK(n_fault == 0);
}

int main(void) {
  TT_RUN(test_latch_first_cause_and_history);
  TT_RUN(test_reaction);
  TT_RUN(test_brake_time_bound);
  TT_RUN(test_inputs);
  TT_RUN(test_i2t);
  TT_RUN(test_speed_position_follow);
  return TT_SUMMARY();
}
