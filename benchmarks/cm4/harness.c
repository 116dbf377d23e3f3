/**
 * @file harness.c
 * @brief Cortex-M4F (QEMU mps2-an386) harness for counting the instructions
 *        executed by one fw_step() call. Driven by benchmarks/bench_cm4_estimate.py.
 *
 *   harness warm  STATE N [force|speed]
 *                           drive the core into closed-loop RUN against the
 *                           locked-mover plant of benchmarks/bench_fw_step.c
 *                           (same warm-up: 0.2 s + N_REC recorded samples,
 *                           FORCE mode with i_q_ref = 2 A; "speed" instead
 *                           runs the speed loop with a 0 rad/s reference),
 *                           then write the final controller state and the
 *                           first N recorded inputs to the host file STATE.
 *   harness count STATE B NB  read STATE and replay NB batches of B inputs,
 *                           each batch from a copy of the saved state (as
 *                           bench_fw_step.c does). Run under `-d exec
 *                           -singlestep`; the script counts the instructions
 *                           executed between fw_step's entry and its return
 *                           to replay_batch().
 *
 * The plant runs in double (soft-float on the M4) but only in `warm`, which
 * is not traced. The firmware core is float32-only.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pmlsm/fw_ctrl.h"

#define N_REC 24000
#define N_MAX 4000

static fw_inputs_t g_rec[N_REC];
static fw_ctrl_t g_base, g_c;
volatile float g_sink;

/* Locked mover at 0.4 rad, dq currents, 10 Euler sub-steps; records inputs.
 * Copied from benchmarks/bench_fw_step.c (keep in step with it). */
static void warm_up(fw_ctrl_t *c, int speed_mode) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  fw_init(c, &cfg);
  fw_set_mode(c, FW_MODE_FORCE);
  fw_set_iq_ref(c, 2.0f);
  if (speed_mode) { /* variant: speed loop active (reference 0, mover locked) */
    fw_set_mode(c, FW_MODE_SPEED);
    fw_set_speed_ref(c, 0.0f);
  }
  fw_controlword(c, FW_CW_SHUTDOWN);
  fw_controlword(c, FW_CW_ENABLE_OPERATION);
  double th = 0.4, id = 0, iq = 0, duty[3] = {0.5, 0.5, 0.5};
  int en = 0;
  const double dt = 1.0 / 24000.0, udc = 300.0;
  int n_total = (int)(0.2 * 24000) + N_REC;
  for (int k = 0; k < n_total; k++) {
    fw_inputs_t in;
    double cs = cos(th), sn = sin(th);
    double ia = id * cs - iq * sn, ib = id * sn + iq * cs;
    in.i_abc_A[0] = (float)ia;
    in.i_abc_A[1] = (float)(-0.5 * ia + 0.8660254 * ib);
    in.i_abc_A[2] = (float)(-0.5 * ia - 0.8660254 * ib);
    in.u_dc_V = (float)udc;
    if (k >= n_total - N_REC) {
      g_rec[k - (n_total - N_REC)] = in;
    }
    fw_outputs_t out;
    fw_step(c, &in, &out);
    if (en) {
      double va = duty[0] * udc, vb = duty[1] * udc, vc = duty[2] * udc;
      double ua = (2 * va - vb - vc) / 3, ub = (vb - vc) / sqrt(3.0);
      double ud = ua * cs + ub * sn, uq = -ua * sn + ub * cs;
      for (int j = 0; j < 10; j++) {
        double Ldd = 0.012 - 0.0012 * tanh(id / 5.0);
        id += dt / 10 * (ud - 0.958 * id) / Ldd;
        iq += dt / 10 * (uq - 0.958 * iq) / 0.018;
      }
    }
    duty[0] = out.duty_abc[0];
    duty[1] = out.duty_abc[1];
    duty[2] = out.duty_abc[2];
    en = out.pwm_enable;
  }
}

/* The only caller of fw_step in `count` mode: the trace counter starts at
 * fw_step's first instruction and stops when control is back in here. */
__attribute__((noinline)) void replay_batch(fw_ctrl_t *c, const fw_inputs_t *in, int n);
__attribute__((noinline)) void replay_batch(fw_ctrl_t *c, const fw_inputs_t *in, int n) {
  fw_outputs_t out;
  for (int k = 0; k < n; k++) {
    fw_step(c, &in[k], &out);
    g_sink += out.duty_abc[0];
  }
}

static int in_run(const fw_ctrl_t *c) {
  return c->phase == FW_START_RUN && fw_fault_code(c) == FW_FAULT_NONE;
}

int main(int argc, char **argv) {
  if (argc >= 4 && strcmp(argv[1], "warm") == 0) {
    int n = atoi(argv[3]);
    if (n < 1 || n > N_MAX) n = N_MAX;
    int speed_mode = argc >= 5 && strcmp(argv[4], "speed") == 0;
    warm_up(&g_base, speed_mode);
    if (!in_run(&g_base)) {
      printf("CM4: warm-up did not reach closed loop (phase %d, fault 0x%04x)\n",
             (int)g_base.phase, (unsigned)fw_fault_code(&g_base));
      return 1;
    }
    FILE *f = fopen(argv[2], "wb");
    if (f == NULL) {
      printf("CM4: cannot open %s\n", argv[2]);
      return 1;
    }
    size_t ok = fwrite(&g_base, sizeof g_base, 1, f);
    ok += fwrite(g_rec, sizeof g_rec[0], (size_t)n, f);
    fclose(f);
    if (ok != 1u + (size_t)n) {
      printf("CM4: short write\n");
      return 1;
    }
    printf("CM4: warm ok phase=RUN sizeof(fw_ctrl_t)=%u inputs=%d\n", (unsigned)sizeof g_base, n);
    return 0;
  }
  if (argc >= 5 && strcmp(argv[1], "count") == 0) {
    int batch = atoi(argv[3]), nb = atoi(argv[4]);
    if (batch < 1 || nb < 1 || batch * nb > N_MAX) {
      printf("CM4: bad batch sizes\n");
      return 1;
    }
    FILE *f = fopen(argv[2], "rb");
    if (f == NULL) {
      printf("CM4: cannot open %s\n", argv[2]);
      return 1;
    }
    size_t ok = fread(&g_base, sizeof g_base, 1, f);
    ok += fread(g_rec, sizeof g_rec[0], (size_t)(batch * nb), f);
    fclose(f);
    if (ok != 1u + (size_t)(batch * nb)) {
      printf("CM4: short read\n");
      return 1;
    }
    /* Batches restart from the saved state: they must span whole injection
     * periods, or the replayed HF response is out of phase and the core
     * (rightly) trips FW_FAULT_EST_HF_LOW. */
    int period = (int)(g_base.cfg.f_pwm_Hz / g_base.cfg.f_inj_Hz + 0.5f);
    if (period < 1 || batch % period != 0) {
      printf("CM4: batch %d is not a multiple of the injection period %d\n", batch, period);
      return 1;
    }
    int all_run = 1;
    for (int b = 0; b < nb; b++) {
      memcpy(&g_c, &g_base, sizeof g_c);
      replay_batch(&g_c, &g_rec[b * batch], batch);
      if (!in_run(&g_c)) all_run = 0;
    }
    printf("CM4: count done batches=%d batch=%d closed_loop=%s phase=%d fault=0x%04x\n", nb,
           batch, all_run ? "yes" : "NO", (int)g_c.phase, (unsigned)fw_fault_code(&g_c));
    return all_run ? 0 : 1;
  }
  printf("usage: harness warm STATE N [force|speed] | harness count STATE BATCH NB\n");
  return 2;
}
