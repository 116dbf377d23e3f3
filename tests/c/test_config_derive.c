/**
 * @file test_config_derive.c
 * @brief Gains and back-EMF levels derived in the drive from the physical
 *        description (fw_config_derive) against the formulas computed here in double.
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_ctrl.h"
#include "test_motors.h"
#include "tinytest.h"

static void test_derive_matches_formulas(void) {
  fw_config_t c;
  fw_config_default(&c);
  test_motor_iron_core_linear(&c);
  c.loops.cur_bw_radps = 1100.0f;
  c.loops.spd_bw_radps = 20.0f;
  fw_config_derive(&c);
  const double ke = M_PI / 0.016, KF = 1.5 * ke * 0.20372; /* 60.0 N/A */
  TT_CHECK_NEAR(KF, 60.0, 0.01);
  TT_CHECK_NEAR(c.loops.cur_kp_V_per_A, 0.008 * 1100.0, 1e-4);
  TT_CHECK_NEAR(c.loops.cur_ki_V_per_As, 2.4 * 1100.0, 1e-2);
  const double kp = 6.0 * 20.0 / KF / ke; /* A per el. rad/s */
  TT_CHECK_NEAR(c.loops.spd_kp_A_per_radps, kp, 1e-5 * kp);
  TT_CHECK_NEAR(c.loops.spd_ki_A_per_rad, kp * 20.0 / 6.0, 1e-5 * kp * 20.0 / 6.0);
  TT_CHECK_NEAR(c.estimator.pll_accel_per_A, ke * KF / 6.0, 1e-5 * ke * KF / 6.0);
  /* observer: poles at -w, w = sqrt(a_d / (3 * 0.05)), a_d = ke * 0.2 * KF * i_max / m */
  const double a_d = ke * 0.2 * KF * (double)c.loops.i_max_A / 6.0;
  const double w = sqrt(a_d / 0.15);
  TT_CHECK(w > 30.0 && w < 2.0 * M_PI * 3000.0 / 40.0); /* inside the bounds */
  TT_CHECK_NEAR(c.estimator.pll_kp, 3.0 * w, 1e-5 * 3.0 * w);
  TT_CHECK_NEAR(c.estimator.pll_ki, 3.0 * w * w, 1e-5 * 3.0 * w * w);
  TT_CHECK_NEAR(c.estimator.pll_kd, w * w * w, 1e-5 * w * w * w);
  TT_CHECK(c.estimator.pll_kd < c.estimator.pll_kp * c.estimator.pll_ki); /* Routh: stable */
  {
    fw_config_t h = c; /* a very heavy mover: the lower bound */
    h.machine.mass_kg = 5.0e4f;
    fw_config_derive(&h);
    TT_CHECK_NEAR(h.estimator.pll_kp, 90.0, 1e-3);
    fw_config_t l = c; /* a very light one: the injection bounds it */
    l.machine.mass_kg = 0.01f;
    fw_config_derive(&l);
    TT_CHECK_NEAR(l.estimator.pll_kp, 3.0 * 2.0 * M_PI * 3000.0 / 40.0, 1e-2);
    fw_config_issue_t issue;
    TT_CHECK(fw_config_check(&l, &issue) == FW_OK); /* within the OD ranges */
  }
  /* fw_init stores the derived gains */
  fw_config_t c2 = c;
  c2.loops.cur_kp_V_per_A = 0.0f;
  c2.estimator.pll_accel_per_A = 0.0f;
  fw_ctrl_t ctrl;
  TT_CHECK(fw_init(&ctrl, &c2) == FW_OK);
  TT_CHECK_NEAR(fw_get_config(&ctrl)->loops.cur_kp_V_per_A, 8.8, 1e-4);
  TT_CHECK_NEAR(fw_get_config(&ctrl)->estimator.pll_accel_per_A, ke * KF / 6.0,
                1e-5 * ke * KF / 6.0);
}

static void test_explicit_gains_kept(void) {
  fw_config_t c;
  fw_config_default(&c);
  TT_CHECK(c.loops.gains_auto == 0u);
  float kp = c.loops.spd_kp_A_per_radps, acc = c.estimator.pll_accel_per_A;
  c.machine.mass_kg = 1.0f;
  fw_config_derive(&c); /* gains_auto = 0: explicit gains stay */
  TT_CHECK(c.loops.spd_kp_A_per_radps == kp && c.estimator.pll_accel_per_A == acc);
  /* the paper defaults are what the derivation gives for the paper motor's mass
   * and a 35 rad/s speed loop (the paper's 0.1 A/(r/min) on this mover) */
  c.machine.mass_kg = 32.13f;
  c.loops.gains_auto = 1u;
  fw_config_derive(&c);
  TT_CHECK_NEAR(c.estimator.pll_accel_per_A, acc, 0.01 * acc);
  TT_CHECK_NEAR(c.loops.spd_kp_A_per_radps, kp, 0.01 * kp);
  /* a bad mass is left for the range check to report */
  c.machine.mass_kg = -1.0f;
  fw_config_issue_t issue;
  TT_CHECK(fw_config_check(&c, &issue) == FW_ERR_RANGE);
}

/* The handover and witness levels are the back-EMF psi_f (pi / tau) v at their speeds,
 * derived whatever gains_auto; the handover speed does not move with psi_f. */
static void check_levels(const fw_config_t *c) {
  /* V per m/s */
  const double k = (double)c->machine.psi_f_Wb * M_PI / (double)c->machine.pole_pitch_m;
  TT_CHECK_NEAR(c->estimator.bemf_e_on_V, k * (double)c->estimator.bemf_v_on_mps, 1e-6 * k);
  TT_CHECK_NEAR(c->estimator.bemf_e_off_V, k * (double)c->estimator.bemf_v_off_mps, 1e-6 * k);
  TT_CHECK_NEAR(c->protection.mon_bemf_min_V, k * (double)c->protection.mon_bemf_min_mps, 1e-6 * k);
}

static void test_bemf_levels_from_speeds(void) {
  fw_config_t c;
  fw_config_default(&c); /* the paper motor: derived already */
  TT_CHECK(c.loops.gains_auto == 0u);
  check_levels(&c);
  TT_CHECK_NEAR(c.estimator.bemf_e_on_V, 10.04, 0.01); /* 0.42 m/s x 23.9 V/(m/s) */
  /* iron_core_linear's file: 0.25 / 0.175 / 0.125 m/s, 40 V per m/s */
  c.machine.psi_f_Wb = 0.20372f;
  c.machine.pole_pitch_m = 0.016f;
  c.estimator.bemf_v_on_mps = 0.25f;
  c.estimator.bemf_v_off_mps = 0.175f;
  c.protection.mon_bemf_min_mps = 0.125f;
  fw_config_derive(&c);
  check_levels(&c);
  TT_CHECK_NEAR(c.estimator.bemf_e_on_V, 10.0, 1e-3);
  TT_CHECK_NEAR(c.estimator.bemf_e_off_V, 7.0, 1e-3);
  TT_CHECK_NEAR(c.protection.mon_bemf_min_V, 5.0, 1e-3);
  /* a stronger magnet (an identified psi_f): the levels follow, the speeds stay */
  c.machine.psi_f_Wb = 0.26f;
  c.loops.gains_auto = 1u;
  fw_config_derive(&c);
  check_levels(&c);
  TT_CHECK(c.estimator.bemf_v_on_mps == 0.25f);
  /* fw_init and fw_set_config store the derived levels, whatever the caller left in them */
  c.estimator.bemf_e_on_V = c.estimator.bemf_e_off_V = c.protection.mon_bemf_min_V = 0.0f;
  fw_ctrl_t ctrl;
  TT_CHECK(fw_init(&ctrl, &c) == FW_OK);
  check_levels(fw_get_config(&ctrl));
  c.machine.psi_f_Wb = 0.16f;
  fw_config_issue_t issue;
  TT_CHECK(fw_set_config(&ctrl, &c, &issue) == FW_OK);
  check_levels(fw_get_config(&ctrl));
  TT_CHECK_NEAR(fw_get_config(&ctrl)->estimator.bemf_e_on_V, 0.25 * M_PI / 0.016 * 0.16, 1e-4);
  /* 0 switches the handover off (level 0); down must stay below up */
  c.estimator.bemf_v_on_mps = 0.0f;
  fw_config_derive(&c);
  TT_CHECK(c.estimator.bemf_e_on_V == 0.0f);
  TT_CHECK(fw_config_check(&c, &issue) == FW_OK);
  c.estimator.bemf_v_on_mps = 0.2f;
  c.estimator.bemf_v_off_mps = 0.2f;
  TT_CHECK(fw_config_check(&c, &issue) == FW_ERR_INCONSISTENT);
  TT_CHECK(issue.field != NULL && strcmp(issue.field, "bemf_v_off_mps") == 0);
}

int main(void) {
  TT_RUN(test_derive_matches_formulas);
  TT_RUN(test_explicit_gains_kept);
  TT_RUN(test_bemf_levels_from_speeds);
  return TT_SUMMARY();
}
