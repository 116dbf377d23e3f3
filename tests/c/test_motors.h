/**
 * @file test_motors.h
 * @brief Motor data the C tests share: the shipped motors' electrical and mechanical
 *        parameters as the drive configuration holds them. They are the values of
 *        sim_fallback/motors/<name>.toml; tests/python/test_c_test_motors.py checks it.
 */
#ifndef PMLSM_TEST_MOTORS_H
#define PMLSM_TEST_MOTORS_H

#include "pmlsm/fw_ctrl.h"

/** iron_core_linear: R, L_d, L_q, psi_f, pole pitch, mover mass (gains derived). */
static inline void test_motor_iron_core_linear(fw_config_t *c) {
  c->machine.R_ohm = 2.4f;
  c->machine.L_d_H = 0.008f;
  c->machine.L_q_H = 0.011f;
  c->machine.psi_f_Wb = 0.20372f;
  c->machine.pole_pitch_m = 0.016f;
  c->machine.mass_kg = 6.0f;
  c->loops.gains_auto = 1u;
}

#endif /* PMLSM_TEST_MOTORS_H */
