/**
 * @file test_cal.c
 * @brief Current-sensor zero calibration at boot (fw_cal, through the core's
 *        fw_step_adc): injected per-phase offsets recovered within the noise's
 *        sigma / sqrt(N) against the mean of the same samples computed here in
 *        double; a zero beyond mon_i_zero_max_A or a spread beyond
 *        mon_i_zero_spread_A is CURRENT_ZERO_CAL and the drive never enables.
 */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_cal.h"
#include "pmlsm/fw_ctrl.h"
#include "tinytest.h"

/* A board's ADC with the power stage off: per-phase offset (counts, real), white
 * Gaussian noise (counts RMS), and an optional sinusoidal current on phase a
 * (counts amplitude: current flowing, which a zero must not be taken from). */
typedef struct {
  double offset[3];
  double noise;
  double sine_a;
  uint64_t rng;
  uint32_t k;
  double sum[3];  /* the reference: the samples the calibration saw, in double */
  double sum2[3];
  uint32_t n;
  uint32_t skip;  /* periods before the calibration's first sample */
} adc_t;

static double uniform(adc_t *a) {
  a->rng = a->rng * 6364136223846793005ull + 1442695040888963407ull;
  return ((double)(a->rng >> 11) + 0.5) / 9007199254740992.0;
}

static double gauss(adc_t *a) {
  const double u1 = uniform(a), u2 = uniform(a);
  return sqrt(-2.0 * log(u1)) * cos(2.0 * M_PI * u2);
}

static void adc_sample(adc_t *a, fw_adc_inputs_t *in) {
  for (int j = 0; j < 3; j++) {
    double x = 2048.0 + a->offset[j] + a->noise * gauss(a);
    if (j == 0) {
      x += a->sine_a * sin(2.0 * M_PI * 50.0 * (double)a->k / 24000.0);
    }
    x = floor(x + 0.5);
    x = x < 0.0 ? 0.0 : (x > 4095.0 ? 4095.0 : x);
    in->i_abc_counts[j] = (uint32_t)x;
    if (a->k >= a->skip && a->n < FW_CAL_SAMPLES) {
      a->sum[j] += x;
      a->sum2[j] += x * x;
    }
  }
  if (a->k >= a->skip && a->n < FW_CAL_SAMPLES) {
    a->n++;
  }
  in->u_dc_counts = 2458u; /* 300 V at the default scaling */
  a->k++;
}

/* Boot the core on the ADC until it leaves NOT READY TO SWITCH ON; returns the
 * periods it took. The PWM must stay off throughout. */
static uint32_t boot(fw_ctrl_t *c, adc_t *a, const fw_config_t *cfg) {
  TT_CHECK(fw_init(c, cfg) == FW_OK);
  TT_CHECK(fw_state(c) == FW_CIA402_NOT_READY_TO_SWITCH_ON);
  TT_CHECK(fw_current_zero_state(c) == FW_CAL_RUNNING);
  a->skip = (uint32_t)ceil(0.005 * (double)cfg->sensing.f_pwm_Hz - 1e-9);
  fw_adc_inputs_t in;
  fw_outputs_t out;
  uint32_t n = 0u, pwm = 0u;
  while (fw_state(c) == FW_CIA402_NOT_READY_TO_SWITCH_ON && n < 5000u) {
    /* a command meanwhile is ignored (the state waits for the self-test) */
    fw_controlword(c, n == 10u ? FW_CW_SHUTDOWN : FW_CW_DISABLE_VOLTAGE);
    adc_sample(a, &in);
    fw_step_adc(c, &in, &out);
    pwm |= out.pwm_enable;
    n++;
  }
  TT_CHECK(pwm == 0u);
  return n;
}

/* Walk to OPERATION ENABLED and run a few periods on mid-scale samples: returns
 * whether the PWM came on in any of them. */
static int try_enable(fw_ctrl_t *c, adc_t *a) {
  fw_controlword(c, FW_CW_SHUTDOWN);
  fw_controlword(c, FW_CW_SWITCH_ON);
  fw_controlword(c, FW_CW_ENABLE_OPERATION);
  fw_adc_inputs_t in;
  fw_outputs_t out;
  int on = 0;
  for (int k = 0; k < 48; k++) {
    adc_sample(a, &in);
    fw_step_adc(c, &in, &out);
    on |= out.pwm_enable != 0u;
  }
  return on;
}

static void test_offsets_recovered(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  fw_ctrl_t c;
  adc_t a;
  memset(&a, 0, sizeof a);
  a.offset[0] = 7.3;
  a.offset[1] = -4.6;
  a.offset[2] = 0.8;
  a.noise = 3.0;
  a.rng = 12345u;
  const uint32_t n = boot(&c, &a, &cfg);
  /* settle (5 ms = 120 periods at 24 kHz) + FW_CAL_SAMPLES */
  TT_CHECK(n == 120u + FW_CAL_SAMPLES);
  TT_CHECK(a.n == FW_CAL_SAMPLES);
  TT_CHECK(fw_state(&c) == FW_CIA402_SWITCH_ON_DISABLED);
  TT_CHECK(fw_fault_code(&c) == FW_FAULT_NONE);
  TT_CHECK(fw_current_zero_state(&c) == FW_CAL_DONE);
  /* noise plus the quantisation's 1/12 count^2, over N samples */
  const double sig_mean = sqrt(a.noise * a.noise + 1.0 / 12.0) / sqrt((double)FW_CAL_SAMPLES);
  for (unsigned j = 0; j < 3u; j++) {
    const double z = (double)fw_current_zero_counts(&c, j);
    const double ref = a.sum[j] / (double)a.n; /* the same samples' mean */
    TT_CHECK_NEAR(z, ref, 1e-3);
    TT_CHECK_NEAR(z, 2048.0 + a.offset[j], 4.0 * sig_mean); /* 0.38 counts */
    const double var = a.sum2[j] / a.n - ref * ref;
    TT_CHECK_NEAR((double)c.cal.spread_counts[j], sqrt(var), 1e-2);
  }
  /* the conversion uses them: a sample at each phase's zero reads 0 A */
  fw_adc_inputs_t in = {{2055u, 2043u, 2049u}, 2458u};
  fw_inputs_t x;
  const float zc[3] = {fw_current_zero_counts(&c, 0u), fw_current_zero_counts(&c, 1u),
                       fw_current_zero_counts(&c, 2u)};
  TT_CHECK(fw_adc_convert(&cfg, zc, &in, &x));
  for (unsigned j = 0; j < 3u; j++) {
    TT_CHECK_NEAR(x.i_abc_A[j], ((double)in.i_abc_counts[j] - (double)zc[j]) *
                                    (double)cfg.sensing.adc_A_per_count, 1e-6);
  }
  TT_CHECK(fabs(x.i_abc_A[0] - (2055.0 - 2048.0) * cfg.sensing.adc_A_per_count) > 0.003);
  /* the drive enables on it */
  a.noise = 0.0;
  memset(a.offset, 0, sizeof a.offset);
  TT_CHECK(try_enable(&c, &a));
  TT_CHECK(fw_fault_code(&c) == FW_FAULT_NONE);
}

static void test_offset_beyond_limit_refused(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  const double lim_counts = cfg.protection.mon_i_zero_max_A / cfg.sensing.adc_A_per_count;
  for (int beyond = 0; beyond < 2; beyond++) {
    fw_ctrl_t c;
    adc_t a;
    memset(&a, 0, sizeof a);
    a.noise = 1.0;
    a.rng = 7u;
    a.offset[1] = beyond ? -(lim_counts + 3.0) : -(lim_counts - 3.0); /* phase b */
    (void)boot(&c, &a, &cfg);
    if (!beyond) {
      TT_CHECK(fw_state(&c) == FW_CIA402_SWITCH_ON_DISABLED);
      TT_CHECK(fw_fault_code(&c) == FW_FAULT_NONE);
      TT_CHECK(try_enable(&c, &a));
      continue;
    }
    /* NOT READY -> FAULT REACTION ACTIVE -> FAULT, never SWITCH ON DISABLED */
    TT_CHECK(fw_fault_code(&c) == FW_FAULT_CURRENT_ZERO_CAL);
    TT_CHECK(fw_state(&c) == FW_CIA402_FAULT_REACTION_ACTIVE ||
             fw_state(&c) == FW_CIA402_FAULT);
    TT_CHECK(!try_enable(&c, &a)); /* refused in FAULT */
    /* a fault reset clears the latch, not the calibration: every enable refused */
    for (int k = 0; k < 3; k++) {
      fw_controlword(&c, 0x0000u);
      fw_controlword(&c, FW_CW_FAULT_RESET);
      TT_CHECK(fw_state(&c) == FW_CIA402_SWITCH_ON_DISABLED);
      TT_CHECK(!try_enable(&c, &a));
      TT_CHECK(fw_fault_code(&c) == FW_FAULT_CURRENT_ZERO_CAL);
      TT_CHECK(fw_state(&c) == FW_CIA402_FAULT);
    }
  }
}

static void test_spread_beyond_limit_refused(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  const double lim_counts = cfg.protection.mon_i_zero_spread_A / cfg.sensing.adc_A_per_count;
  /* a noisy ADC: zero mean, RMS 1.3 x the limit on phase c */
  {
    fw_ctrl_t c;
    adc_t a;
    memset(&a, 0, sizeof a);
    a.noise = 1.3 * lim_counts;
    a.rng = 99u;
    (void)boot(&c, &a, &cfg);
    TT_CHECK(fw_fault_code(&c) == FW_FAULT_CURRENT_ZERO_CAL);
    TT_CHECK(!try_enable(&c, &a));
  }
  /* current flowing on phase a: a 50 Hz sine of zero mean (so not the zero's
   * check) and RMS 1.2 x the limit */
  {
    fw_ctrl_t c;
    adc_t a;
    memset(&a, 0, sizeof a);
    a.noise = 1.0;
    a.sine_a = 1.2 * lim_counts * sqrt(2.0);
    a.rng = 5u;
    (void)boot(&c, &a, &cfg);
    TT_CHECK_NEAR((double)fw_current_zero_counts(&c, 0u), 2048.0, 0.2 * lim_counts);
    TT_CHECK(fw_fault_code(&c) == FW_FAULT_CURRENT_ZERO_CAL);
  }
  /* the same noise under the limit passes */
  {
    fw_ctrl_t c;
    adc_t a;
    memset(&a, 0, sizeof a);
    a.noise = 0.7 * lim_counts;
    a.rng = 99u;
    (void)boot(&c, &a, &cfg);
    TT_CHECK(fw_fault_code(&c) == FW_FAULT_NONE);
    TT_CHECK(fw_state(&c) == FW_CIA402_SWITCH_ON_DISABLED);
  }
}

/* The judgement at enable uses the configuration then in force: a limit written
 * after the boot that the measured zero exceeds refuses the enable. */
static void test_limit_written_after_boot(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  fw_ctrl_t c;
  adc_t a;
  memset(&a, 0, sizeof a);
  a.offset[2] = 20.0; /* 0.24 A */
  a.noise = 1.0;
  a.rng = 3u;
  (void)boot(&c, &a, &cfg);
  TT_CHECK(fw_fault_code(&c) == FW_FAULT_NONE);
  fw_config_t tight = cfg;
  tight.protection.mon_i_zero_max_A = 0.1f;
  fw_config_issue_t iss;
  TT_CHECK(fw_set_config(&c, &tight, &iss) == FW_OK);
  TT_CHECK(!try_enable(&c, &a));
  TT_CHECK(fw_fault_code(&c) == FW_FAULT_CURRENT_ZERO_CAL);
  /* out of range: refused with the field named */
  tight.protection.mon_i_zero_max_A = 0.0f;
  TT_CHECK(fw_set_config(&c, &tight, &iss) == FW_ERR_RANGE);
  TT_CHECK(strcmp(iss.field, "mon_i_zero_max_A") == 0);
}

/* Stepped in physical units there are no raw samples: nothing to calibrate, the
 * nominal zero, SWITCH ON DISABLED after the first period. */
static void test_physical_units_path(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  fw_ctrl_t c;
  TT_CHECK(fw_init(&c, &cfg) == FW_OK);
  fw_controlword(&c, FW_CW_SHUTDOWN); /* ignored: not ready */
  TT_CHECK(fw_state(&c) == FW_CIA402_NOT_READY_TO_SWITCH_ON);
  const fw_inputs_t in = {{0.0f, 0.0f, 0.0f}, 300.0f};
  fw_outputs_t out;
  fw_step(&c, &in, &out);
  TT_CHECK(fw_state(&c) == FW_CIA402_SWITCH_ON_DISABLED);
  TT_CHECK(fw_current_zero_state(&c) == FW_CAL_NONE);
  TT_CHECK(fw_current_zero_counts(&c, 1u) == cfg.sensing.adc_offset_counts);
}

int main(void) {
  TT_RUN(test_offsets_recovered);
  TT_RUN(test_offset_beyond_limit_refused);
  TT_RUN(test_spread_beyond_limit_refused);
  TT_RUN(test_limit_written_after_boot);
  TT_RUN(test_physical_units_path);
  return TT_SUMMARY();
}
