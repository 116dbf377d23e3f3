/**
 * @file fw_mon.c
 * @brief Estimator integrity monitor (see fw_mon.h and docs/integrity.md).
 *
 * HF angle witness. With a square wave u on d^ and dtheta = theta - theta^,
 * the raw current difference per sample, sign-demodulated, is
 *     e_d = Ts u (S + D cos 2 dtheta) / 2,   e_q = Ts u D sin 2 dtheta / 2,
 * S = 1/L_d + 1/L_q, D = 1/L_d - 1/L_q. With the locked response
 * e_ref = Ts u / L_d (learnt at standstill) and rho = S / D:
 *     cos 2 dtheta = (e_d / e_ref)(rho + 1) - rho,
 *     sin 2 dtheta = (e_q / e_ref)(rho + 1),
 * so |dtheta| (mod pi) follows from atan2 over the whole range, where the
 * PLL's linearised error (E_q / E_d) L_q / (L_q - L_d) folds back to zero at
 * pi/2. The witness uses the raw difference, not the extractor's output: it
 * does not share the PLL's signal path.
 *
 * Back-EMF witness. In the estimated frame the voltage equation residual
 *     r_d = u_d - R i_d + w^ L_q i_q,   r_q = u_q - R i_q - w^ L_d i_d
 * (less L di/dt) is the back-EMF w psi_f (-sin dtheta, cos dtheta) once low-passed; its
 * angle and magnitude must agree with the estimate where it is large enough
 * to be measured.
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_ctrl.h"

#define MON_HF_TAU_S 0.002f   /* HF response low-pass */
#define MON_SLOW_TAU_S 0.005f /* residual, current-sum, current-error low-pass */
#define MON_OFF_TAU_S 0.02f   /* offset learning low-pass */
#define MON_OFF_WAIT_S 0.05f  /* PWM off this long before offsets are learnt */
#define MON_BEMF_RATIO 2.0f   /* |r| / (|w^| psi_f) must lie in [1/2, 2] */
#define MON_CTRL_SHARE 0.5f   /* current-error limit as a share of i_max_A */
#define MON_ACCEL_MARGIN 2.0f
#define MON_EVAL_STEPS 8u
#define MON_SUM_SHARE 0.03f   /* current-sum limit grows by this share of sum |i_k| */     /* witnesses judged every 8 periods (3 kHz at 24 kHz) */ /* disturbance limit: 2 x the thrust acceleration at i_max */

static float lp_coef(float tau_s, float dt_s) { return 1.0f - expf(-dt_s / tau_s); }

static float persist(float t, bool over, float dt) { return over ? t + dt : 0.0f; }

void fw_mon_init(fw_mon_t *m, const fw_config_t *cfg, float dt_s) {
  memset(m, 0, sizeof(*m));
  m->dt_s = dt_s;
  m->inv_dt = 1.0f / dt_s;
  m->angle_max_rad = cfg->mon_angle_max_rad;
  m->bemf_max_rad = cfg->mon_bemf_max_rad;
  m->bemf_min_V = cfg->mon_bemf_min_V;
  m->detect_s = cfg->mon_detect_time_s;
  m->i_sum_max_A = cfg->i_sum_max_A;
  m->i_offset_max_A = cfg->i_offset_max_A;
  m->i_ctrl_max_A = MON_CTRL_SHARE * cfg->i_max_A;
  m->accel_max = MON_ACCEL_MARGIN * cfg->pll_accel_per_A * cfg->i_max_A;
  m->R_ohm = cfg->R_ohm;
  m->L_d_H = cfg->L_d_H;
  m->L_q_H = cfg->L_q_H;
  m->psi_f_Wb = cfg->psi_f_Wb;
  m->a_hf = lp_coef(MON_HF_TAU_S, dt_s);
  m->a_slow = lp_coef(MON_SLOW_TAU_S, dt_s);
  m->a_off = lp_coef(MON_OFF_TAU_S, dt_s);
}

void fw_mon_learn_offsets(fw_mon_t *m, const float i_abc_A[3]) {
  m->off_time_s += m->dt_s;
  if (m->off_time_s < MON_OFF_WAIT_S) {
    return; /* currents still decaying after the last switch-off */
  }
  for (int k = 0; k < 3; k++) {
    m->off_f[k] += m->a_off * (i_abc_A[k] - m->off_f[k]);
  }
}

fw_fault_t fw_mon_enable(fw_mon_t *m) {
  for (int k = 0; k < 3; k++) {
    if (fabsf(m->off_f[k]) > m->i_offset_max_A) {
      return FW_FAULT_CURRENT_SENSOR_OFFSET;
    }
  }
  memcpy(m->offset_A, m->off_f, sizeof(m->offset_A));
  m->e_ref_A = 0.0f;
  m->e_d_f = m->e_q_f = m->r_d_f = m->r_q_f = m->ictrl_f = m->w_f = 0.0f;
  m->t_hf = m->t_bemf = m->t_accel = m->t_ctrl = 0.0f;
  m->verdict = FW_FAULT_NONE;
  m->angle_hf_rad = m->angle_bemf_rad = m->e_bemf_V = 0.0f;
  return FW_FAULT_NONE;
}

void fw_mon_compensate(const fw_mon_t *m, float i_abc_A[3]) {
  for (int k = 0; k < 3; k++) {
    i_abc_A[k] -= m->offset_A[k];
  }
}

/** x reduced modulo pi into [-pi/2, pi/2). */
static float wrap_half_pi(float x) { return 0.5f * fw_wrap_pi_f32(2.0f * x); }

fw_fault_t fw_mon_saliency(fw_mon_t *m, const fw_config_t *cfg, float y_dd, float y_qd,
                           float y_dq, float y_qq, float Ts_u_Vs) {
  const float b = 0.5f * (y_qd + y_dq);
  const float mean = 0.5f * (y_dd + y_qq);
  const float half = 0.5f * (y_dd - y_qq);
  const float r = sqrtf(half * half + b * b);
  const float l_big = mean + r;   /* Ts u / L_small */
  const float l_small = mean - r; /* Ts u / L_large */
  const bool q_larger = cfg->L_q_H > cfg->L_d_H;
  if (!(l_small > 0.0f) || !(l_big > 0.0f)) {
    m->sal_meas = 0.0f;
    return FW_FAULT_SALIENCY_MISMATCH; /* no inductive response on some axis */
  }
  m->sal_meas = l_big / l_small - 1.0f;
  m->L_small_meas_H = Ts_u_Vs / l_big;
  m->L_large_meas_H = Ts_u_Vs / l_small;
  /* axis of the larger response (smaller inductance) in the estimated frame;
   * it should be d^ when L_q > L_d, q^ otherwise */
  const float axis = 0.5f * atan2f(2.0f * b, y_dd - y_qq);
  m->sal_axis_rad = wrap_half_pi(axis - (q_larger ? 0.0f : 0.5f * FW_PI_F32));
  const float L_lo = q_larger ? cfg->L_d_H : cfg->L_q_H;
  const float L_hi = q_larger ? cfg->L_q_H : cfg->L_d_H;
  const float sal_cfg = L_hi / L_lo - 1.0f;
  /* measured and configured saliency must agree within a factor (1 + tol) */
  const float ratio = m->sal_meas / sal_cfg;
  const float f = 1.0f + cfg->mon_sal_tol;
  if (m->sal_meas < cfg->saliency_min || ratio > f || ratio * f < 1.0f) {
    return FW_FAULT_SALIENCY_MISMATCH;
  }
  if (fabsf(m->sal_axis_rad) > m->angle_max_rad) {
    return FW_FAULT_EST_HF_ANGLE;
  }
  /* learnt references for the running HF witness (measured, not configured) */
  m->e_ref_A = q_larger ? l_big : l_small;
  m->rho = (q_larger ? 1.0f : -1.0f) * (l_big + l_small) / (l_big - l_small);
  return FW_FAULT_NONE;
}

void fw_mon_run_start(fw_mon_t *m) {
  m->e_d_f = m->e_ref_A;
  m->e_q_f = 0.0f;
  m->r_d_f = m->r_q_f = m->ictrl_f = m->w_f = 0.0f;
  m->t_hf = m->t_bemf = m->t_accel = m->t_ctrl = 0.0f;
  m->verdict = FW_FAULT_NONE;
  m->eval_k = 0u;
}

/** First timed-out witness of those judged every MON_EVAL_STEPS periods. */
static fw_fault_t judge(const fw_mon_t *m) {
  if (m->t_ctrl >= m->detect_s) {
    return FW_FAULT_CURRENT_CONTROL;
  }
  if (m->t_hf >= m->detect_s) {
    return FW_FAULT_EST_HF_ANGLE;
  }
  if (m->t_bemf >= m->detect_s) {
    return FW_FAULT_EST_BEMF_MISMATCH;
  }
  if (m->t_accel >= m->detect_s) {
    return FW_FAULT_EST_ACCEL_IMPLAUSIBLE;
  }
  return FW_FAULT_NONE;
}

fw_fault_t fw_mon_motion(const fw_mon_t *m, float e_start_max_V) {
  float e = sqrtf(m->r_d_f * m->r_d_f + m->r_q_f * m->r_q_f);
  return e > e_start_max_V ? FW_FAULT_MOVING_AT_ENABLE : FW_FAULT_NONE;
}

fw_fault_t fw_mon_update(fw_mon_t *m, const fw_mon_in_t *in) {
  const float dt = m->dt_s;
  /* current sum: a star-connected winding has i_a + i_b + i_c = 0. Judged with
   * the power stage on, after offset compensation (with PWM off a constant
   * sum is an offset: the per-phase offset check at enable names it). */
  float isum = fabsf(in->i_abc_A[0] + in->i_abc_A[1] + in->i_abc_A[2]);
  m->isum_f += m->a_slow * (isum - m->isum_f);
  /* limit: a floor plus a share of the phase current amplitude (a gain error g on
   * one phase gives a sum of about 0.64 g |i|) */
  float imag = fabsf(in->i_abc_A[0]) + fabsf(in->i_abc_A[1]) + fabsf(in->i_abc_A[2]);
  m->imag_f += m->a_slow * (imag - m->imag_f); /* mean of the three = 4/pi |i|_peak / ... */
  m->t_sum = persist(m->t_sum,
                     in->pwm_on && m->isum_f > m->i_sum_max_A + MON_SUM_SHARE * m->imag_f, dt);

  if (in->pwm_on) {
    m->off_time_s = 0.0f;
    /* L di/dt as a per-sample difference: noisy alone, clean once low-passed */
    float r[2];
    fw_bemf_residual(in->u_dq_V, in->i_dq_A, m->i_prev_A, m->inv_dt, in->omega_hat_radps,
                     m->R_ohm, m->L_d_H, m->L_q_H, r);
    m->r_d_f += m->a_slow * (r[0] - m->r_d_f);
    m->r_q_f += m->a_slow * (r[1] - m->r_q_f);
    /* the speed the residual is compared with goes through the same low-pass:
     * otherwise the 5 ms lag of the residual alone reads as a mismatch whenever
     * the speed changes fast (2 m/s -> 0 in 10 ms at full thrust) */
    m->w_f += m->a_slow * (in->omega_hat_radps - m->w_f);
  }

  if (!in->running) {
    m->t_hf = m->t_bemf = m->t_accel = m->t_ctrl = 0.0f;
    m->verdict = FW_FAULT_NONE;
    m->eval_k = 0u;
  } else {
    /* filters every period (cheap) */
    if (in->hf_valid) {
      m->e_d_f += m->a_hf * (in->e_hf_dq_A[0] - m->e_d_f);
      m->e_q_f += m->a_hf * (in->e_hf_dq_A[1] - m->e_q_f);
    }
    float ed = in->i_dq_ref_A[0] - in->i_dq_A[0];
    float eq = in->i_dq_ref_A[1] - in->i_dq_A[1];
    m->ictrl_f += m->a_slow * (ed * ed + eq * eq - m->ictrl_f); /* mean-square error */
    /* judgements (atan2, sqrt) once every MON_EVAL_STEPS periods: the filters
     * are far slower than that, the detection budget is 20 ms */
    if (++m->eval_k >= MON_EVAL_STEPS) {
      m->eval_k = 0u;
      const float dte = dt * (float)MON_EVAL_STEPS;
      /* HF angle */
      if (m->e_ref_A > 0.0f) {
        float g = (m->rho + 1.0f) / m->e_ref_A;
        float c2 = m->e_d_f * g - m->rho;
        float s2 = m->e_q_f * g;
        m->angle_hf_rad = 0.5f * fabsf(atan2f(s2, c2));
      }
      m->t_hf = persist(m->t_hf, m->angle_hf_rad > m->angle_max_rad, dte);

      /* back-EMF residual */
      float e_hat = fabsf(m->w_f) * m->psi_f_Wb;
      float e_meas = sqrtf(m->r_d_f * m->r_d_f + m->r_q_f * m->r_q_f);
      m->e_bemf_V = e_meas;
      bool bad = false;
      if (e_hat > m->bemf_min_V || e_meas > m->bemf_min_V) {
        if (e_hat * MON_BEMF_RATIO < e_meas || e_meas * MON_BEMF_RATIO < e_hat) {
          bad = true;
          m->angle_bemf_rad = FW_PI_F32; /* magnitude disagrees: no angle to speak of */
        } else {
          float ang = atan2f(-m->r_d_f, m->r_q_f);
          if (m->w_f < 0.0f) {
            ang = fw_wrap_pi_f32(ang + FW_PI_F32);
          }
          m->angle_bemf_rad = fabsf(ang);
          bad = m->angle_bemf_rad > m->bemf_max_rad;
        }
      } else {
        m->angle_bemf_rad = 0.0f;
      }
      m->t_bemf = persist(m->t_bemf, bad, dte);

      /* acceleration plausibility */
      m->t_accel = persist(
          m->t_accel, m->accel_max > 0.0f && fabsf(in->accel_dist_radps2) > m->accel_max, dte);

      /* current control */
      m->t_ctrl = persist(m->t_ctrl, m->ictrl_f > m->i_ctrl_max_A * m->i_ctrl_max_A, dte);
      m->verdict = (uint32_t)judge(m); /* the four timers change only here */
    }
  }

  if (m->t_sum >= m->detect_s) {
    return FW_FAULT_CURRENT_SENSOR_SUM;
  }
  return (fw_fault_t)m->verdict;
}
