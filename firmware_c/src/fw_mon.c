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

#include "pmlsm/fw_mon.h"

#define MON_HF_TAU_S 0.002f   /* HF response low-pass */
#define MON_SLOW_TAU_S 0.005f /* residual, current-sum, current-error low-pass */
#define MON_OFF_TAU_S 0.02f   /* offset learning low-pass */
#define MON_OFF_WAIT_S 0.05f  /* PWM off this long before offsets are learnt */
#define MON_BEMF_RATIO 2.0f   /* |r| / (|w^| psi_f) must lie in [1/2, 2] */
#define MON_CTRL_SHARE 0.5f   /* current-error limit as a share of i_max_A */
#define MON_ACCEL_MARGIN 2.0f /* disturbance limit: 2 x the thrust acceleration at i_max */
#define MON_EVAL_STEPS FW_MON_EVAL_STEPS /* witnesses judged every 8 periods (3 kHz at 24 kHz) */
#define MON_SUM_SHARE 0.03f   /* current-sum limit grows by this share of sum |i_k| */

_Static_assert(sizeof(((fw_mon_t *)0)->inv_n) / sizeof(float) == MON_EVAL_STEPS + 1u,
               "block tables hold n = 0..MON_EVAL_STEPS");

static float lp_coef(float tau_s, float dt_s) { return 1.0f - expf(-dt_s / tau_s); }

static float persist(float t, bool over, float dt) { return over ? t + dt : 0.0f; }

/** Clear the sums of the running witnesses' block (closed loop (re)starts). */
static void sums_clear_run(fw_mon_t *m) {
  m->s_rd = m->s_rq = m->s_w = m->s_ed = m->s_eq = m->s_ictrl = 0.0f;
  /* the periods of the block so far are not in the sums (eval_k: 0 at a
   * block's end, the periods since its start in mid-block) */
  m->miss_pwm = m->miss_hf = m->miss_run = m->eval_k;
}

/** Closed loop (re)starts: the block's running sums restart; the residual's
 *  L di/dt restarts from the last current the power stage drove (zero once it
 *  has been off for a block: fw_mon_block). */
static void sums_restart(fw_mon_t *m) {
  sums_clear_run(m);
  m->i_prev_A[0] = m->i_last_A[0];
  m->i_prev_A[1] = m->i_last_A[1];
}

void fw_mon_init(fw_mon_t *m, const fw_config_t *cfg, float dt_s) {
  memset(m, 0, sizeof(*m));
  m->dt_s = dt_s;
  m->inv_dt = 1.0f / dt_s;
  m->angle_max_rad = cfg->protection.mon_angle_max_rad;
  m->bemf_max_rad = cfg->protection.mon_bemf_max_rad;
  m->bemf_min_V = cfg->protection.mon_bemf_min_V;
  m->bemf_i_tol = cfg->protection.mon_bemf_i_tol;
  m->L_q_psi = cfg->machine.L_q_H / cfg->machine.psi_f_Wb;
  m->detect_s = cfg->protection.mon_detect_time_s;
  m->i_sum_max_A = cfg->protection.i_sum_max_A;
  m->i_offset_max_A = cfg->protection.i_offset_max_A;
  m->i_ctrl_max_A = MON_CTRL_SHARE * cfg->loops.i_max_A;
  m->accel_max = MON_ACCEL_MARGIN * cfg->estimator.pll_accel_per_A * cfg->loops.i_max_A;
  m->R_ohm = cfg->machine.R_ohm;
  m->L_d_H = cfg->machine.L_d_H;
  m->L_q_H = cfg->machine.L_q_H;
  m->psi_f_Wb = cfg->machine.psi_f_Wb;
  m->a_off = lp_coef(MON_OFF_TAU_S, dt_s);
  /* block low-passes: n periods of a per-period low-pass with a constant input */
  for (uint32_t n = 0u; n <= MON_EVAL_STEPS; n++) {
    m->a_hf_n[n] = lp_coef(MON_HF_TAU_S, (float)n * dt_s);
    m->a_slow_n[n] = lp_coef(MON_SLOW_TAU_S, (float)n * dt_s);
    m->inv_n[n] = n > 0u ? 1.0f / (float)n : 0.0f;
  }
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
  m->r_mag_V = 0.0f; /* sqrtf(0) */
  m->t_hf = m->t_bemf = m->t_accel = m->t_ctrl = 0.0f;
  m->verdict = FW_FAULT_NONE;
  m->angle_hf_rad = m->angle_bemf_rad = m->e_bemf_V = 0.0f;
  sums_restart(m);
  return FW_FAULT_NONE;
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
  const bool q_larger = cfg->machine.L_q_H > cfg->machine.L_d_H;
  if (!(l_small > 0.0f) || !(l_big > 0.0f)) {
    m->sal_meas = 0.0f;
    return FW_FAULT_SALIENCY_MISMATCH; /* no inductive response on some axis */
  }
  m->sal_meas = l_big / l_small - 1.0f;
  m->L_small_meas_H = Ts_u_Vs / l_big;
  m->L_large_meas_H = Ts_u_Vs / l_small;
  /* axis of the larger response (smaller inductance) in the estimated frame;
   * it should be d^ when L_q > L_d, q^ otherwise */
  const float axis = 0.5f * fw_atan2_f32(2.0f * b, y_dd - y_qq);
  m->sal_axis_rad = wrap_half_pi(axis - (q_larger ? 0.0f : 0.5f * FW_PI_F32));
  const float L_lo = q_larger ? cfg->machine.L_d_H : cfg->machine.L_q_H;
  const float L_hi = q_larger ? cfg->machine.L_q_H : cfg->machine.L_d_H;
  const float sal_cfg = L_hi / L_lo - 1.0f;
  /* measured and configured saliency must agree within a factor (1 + tol) */
  const float ratio = m->sal_meas / sal_cfg;
  const float f = 1.0f + cfg->protection.mon_sal_tol;
  if (m->sal_meas < cfg->protection.saliency_min || ratio > f || ratio * f < 1.0f) {
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
  m->r_mag_V = 0.0f; /* sqrtf(0) */
  m->t_hf = m->t_bemf = m->t_accel = m->t_ctrl = 0.0f;
  m->verdict = FW_FAULT_NONE;
  sums_restart(m);
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

/** x low-passed over n periods of constant input u (n <= MON_EVAL_STEPS):
 *  x + (1 - (1 - a)^n) (u - x), coefficients from the table a_n. */
static float lp_n(float x, float sum, uint32_t n, const float *a_n, const float *inv_n) {
  return x + a_n[n] * (sum * inv_n[n] - x);
}

/** End of a block of MON_EVAL_STEPS periods: the low-passes on the block
 *  means, then the judgements (atan2, sqrt): the filters are far slower than
 *  a block, the detection budget is 20 ms. */
FW_NOINLINE void fw_mon_block(fw_mon_t *m, bool pwm_on, bool running, float accel_dist_radps2) {
  const float dte = m->dt_s * (float)MON_EVAL_STEPS;
  const float *inv_n = m->inv_n;
  /* current sum, every period of the block (PWM on or off) */
  const float inv8 = 1.0f / (float)MON_EVAL_STEPS;
  const float a8 = m->a_slow_n[MON_EVAL_STEPS];
  m->isum_f += a8 * (m->s_isum * inv8 - m->isum_f);
  m->imag_f += a8 * (m->s_imag * inv8 - m->imag_f); /* mean of the three = 4/pi |i|_peak / ... */
  m->s_isum = m->s_imag = 0.0f;
  m->t_sum = persist(m->t_sum,
                     pwm_on && m->isum_f > m->i_sum_max_A + MON_SUM_SHARE * m->imag_f, dte);
  m->sum_bad = (uint32_t)(m->t_sum >= m->detect_s);
  /* back-EMF residual over the periods with PWM on: L di/dt summed is
   * L (i_last - i_prev) / T */
  const uint32_t np = MON_EVAL_STEPS - m->miss_pwm;
  if (np > 0u) {
    const float sd = m->s_rd - m->L_d_H * (m->i_last_A[0] - m->i_prev_A[0]) * m->inv_dt;
    const float sq = m->s_rq - m->L_q_H * (m->i_last_A[1] - m->i_prev_A[1]) * m->inv_dt;
    m->i_prev_A[0] = m->i_last_A[0];
    m->i_prev_A[1] = m->i_last_A[1];
    m->r_d_f = lp_n(m->r_d_f, sd, np, m->a_slow_n, inv_n);
    m->r_q_f = lp_n(m->r_q_f, sq, np, m->a_slow_n, inv_n);
    m->w_f = lp_n(m->w_f, m->s_w, np, m->a_slow_n, inv_n);
  }
  if (!pwm_on) {
    /* The power stage is off: the current it drove (a braking current of 20 A,
     * say) decays through the freewheeling diodes within L i / u_dc, about a
     * millisecond, and is no start for the L di/dt of the next switch-on: from
     * zero, the current the bridge then starts from. Otherwise the first block
     * after an enable reads L di/dt = L i / T (thousands of volts) as a
     * residual, which the motion check sees 15 ms later as a moving mover. A
     * switch-off shorter than a block keeps the last current, which is then
     * still flowing. */
    m->i_prev_A[0] = m->i_prev_A[1] = 0.0f;
    m->i_last_A[0] = m->i_last_A[1] = 0.0f;
  }
  const uint32_t nh = MON_EVAL_STEPS - m->miss_hf, nr = MON_EVAL_STEPS - m->miss_run;
  if (nh > 0u) {
    m->e_d_f = lp_n(m->e_d_f, m->s_ed, nh, m->a_hf_n, inv_n);
    m->e_q_f = lp_n(m->e_q_f, m->s_eq, nh, m->a_hf_n, inv_n);
  }
  if (nr > 0u) {
    m->ictrl_f = lp_n(m->ictrl_f, m->s_ictrl, nr, m->a_slow_n, inv_n);
  }
  sums_clear_run(m);
  /* the residual's magnitude: the motion check's (fw_mon_motion) and the
   * witness's below */
  const float e_meas = sqrtf(m->r_d_f * m->r_d_f + m->r_q_f * m->r_q_f);
  m->r_mag_V = e_meas;
  if (!running) {
    /* start-up: the residual's magnitude is the motion check's statistic */
    m->e_bemf_V = e_meas;
    return;
  }
  /* HF angle */
  if (m->e_ref_A > 0.0f) {
    float g = (m->rho + 1.0f) / m->e_ref_A;
    float c2 = m->e_d_f * g - m->rho;
    float s2 = m->e_q_f * g;
    m->angle_hf_rad = 0.5f * fabsf(fw_atan2_f32(s2, c2));
  }
  m->t_hf = persist(m->t_hf, m->angle_hf_rad > m->angle_max_rad, dte);

  /* back-EMF residual */
  float e_hat = fabsf(m->w_f) * m->psi_f_Wb;
  m->e_bemf_V = e_meas;
  bool bad = false;
  /* the model's error grows with the current (R, L_q off by bemf_i_tol): the
   * witness judges above it, and allows it in the magnitude and the angle */
  const float i_abs = 0.5f * m->imag_f; /* (|i_a| + |i_b| + |i_c|) / 2 ~ |i| */
  const float e_tol = m->bemf_i_tol * (m->R_ohm + fabsf(m->w_f) * m->L_q_H) * i_abs;
  const float e_min = m->bemf_min_V + e_tol;
  if (e_hat > e_min || e_meas > e_min) {
    if (e_hat * MON_BEMF_RATIO + e_tol < e_meas ||
        (e_meas + e_tol) * MON_BEMF_RATIO < e_hat) {
      bad = true;
      m->angle_bemf_rad = FW_PI_F32; /* magnitude disagrees: no angle to speak of */
    } else {
      float ang = fw_atan2_f32(-m->r_d_f, m->r_q_f);
      if (m->w_f < 0.0f) {
        ang = fw_wrap_pi_f32(ang + FW_PI_F32);
      }
      m->angle_bemf_rad = fabsf(ang);
      bad = m->angle_bemf_rad > m->bemf_max_rad + m->bemf_i_tol * m->L_q_psi * i_abs;
    }
  } else {
    m->angle_bemf_rad = 0.0f;
  }
  m->t_bemf = persist(m->t_bemf, bad, dte);

  /* acceleration plausibility */
  m->t_accel = persist(
      m->t_accel, m->accel_max > 0.0f && fabsf(accel_dist_radps2) > m->accel_max, dte);

  /* current control */
  m->t_ctrl = persist(m->t_ctrl, m->ictrl_f > m->i_ctrl_max_A * m->i_ctrl_max_A, dte);
  m->verdict = (uint32_t)judge(m); /* the four timers change only here */
}
