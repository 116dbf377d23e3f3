/**
 * @file harness.c
 * @brief Cortex-M4F (QEMU mps2-an386) harness for counting the instructions
 *        executed by one fw_step() call, by the drive application's control and
 *        supervision interrupts and by its background loop. Driven by
 *        benchmarks/bench_cm4_estimate.py.
 *
 *   harness warm  STATE N [force|speed]
 *                           drive the core into closed-loop RUN against the
 *                           locked-mover plant of benchmarks/bench_fw_step.c
 *                           (same warm-up, benchmarks/locked_mover.h: 0.2 s + N_REC recorded samples,
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
 *   harness count_isr STATE B NB  as count, but through the drive application's
 *                           two interrupts of a period, on the recorded
 *                           inputs turned back into ADC counts with the
 *                           configured scaling: per period the control
 *                           interrupt fw_app_isr (ADC counts -> the core's
 *                           conversion -> fw_step_into -> duties; stages the
 *                           integrity monitor's inputs and pends the
 *                           supervision), then the supervision interrupt
 *                           fw_app_supervise (integrity monitor, protections,
 *                           the period's raw snapshot published to the
 *                           background's ring), as the board runs them (the
 *                           supervision is pended by, and tail-chained to,
 *                           the control interrupt). The script counts from
 *                           fw_app_isr's entry to its return to
 *                           replay_isr_batch(). The ring is emptied between
 *                           periods as the background would (not counted).
 *   harness count_sup STATE B NB  the same loop; the script counts from
 *                           fw_app_supervise's entry to its return to
 *                           replay_isr_batch().
 *   harness count_bg STATE B NB  the same loop, but the drive application's
 *                           background loop (fw_app_background: CANopen
 *                           receive and commands, completing the period's
 *                           snapshot, faults, serial telemetry, the OD, CANopen
 *                           transmit) runs once after every period instead of
 *                           the drain; the script counts from its entry to its
 *                           return to replay_isr_batch() (the interrupts are
 *                           not counted).
 *                           In the count modes the harness fails (exit 1,
 *                           closed_loop=NO and the batch's fault code printed)
 *                           when the controller is not in RUN without a fault
 *                           at the end of any batch, or when (count_isr/sup/bg)
 *                           a supervision interrupt found a hard fault or a
 *                           period's supervision was missed: a faulted drive is
 *                           never measured silently.
 *   harness replay TRACE OUT  processor-in-the-loop: read a trace (magic
 *                           "PILT", n steps, n events, sizeof(fw_config_t),
 *                           the configuration, events {step, kind, value}
 *                           and n fw_inputs_t recorded from a closed-loop
 *                           simulation), run fw_init + the events + fw_step
 *                           over the inputs and write per step {duty_abc[3],
 *                           theta_hat, fault, pwm} to OUT. Built for the host
 *                           and for the M4 from the same sources, so the two
 *                           outputs can be compared (benchmarks/pil.py).
 *                           Each period is pil_period(): fw_step_into (the
 *                           control half) then fw_supervise (the supervision
 *                           half), each through a volatile pointer, exactly
 *                           what fw_step does.
 *   harness replay TRACE OUT STATES KS  the same, and the controller state
 *                           at the start of each step K0 (before that step's
 *                           events) written to STATES, one fw_ctrl_t per K0;
 *                           KS: the windows [K0, K1) as uint32 pairs, K0
 *                           ascending (a file: semihosting's command line is
 *                           short).
 *   harness window TRACE STATES OUT KS  for each window
 *                           [K0, K1) of KS, in order: load its state from STATES (as
 *                           `replay` wrote it) and replay the trace's steps
 *                           K0..K1-1 (events included) through pil_period();
 *                           write per step the `replay` record followed by
 *                           {speed_hat_mps, start phase, bemf_active, 2 pad}
 *                           to OUT. Run under `-d exec` (pil.py --cycles):
 *                           the script counts fw_step_into and fw_supervise
 *                           per period, each until control is back in
 *                           pil_period().
 *
 * The plant runs in double (soft-float on the M4) but only in `warm`, which
 * is not traced. The firmware core is float32-only.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pmlsm/fw_app.h"
#include "pmlsm/fw_ctrl.h"
#include "../locked_mover.h"

#define N_REC 24000
#define N_MAX 4000

static fw_inputs_t g_rec[N_REC];
static fw_ctrl_t g_base, g_c;
volatile float g_sink;

/* The image is linked with -flto (as the CM4 firmware is). fw_step is called
 * through a volatile pointer, so LTO can neither inline it into the loop below
 * nor replace it by a specialised clone: the traced entry is the real fw_step. */
static void (*volatile g_step)(fw_ctrl_t *, const fw_inputs_t *, fw_outputs_t *) = fw_step;

/* The only caller of fw_step in `count` mode: the trace counter starts at
 * fw_step's first instruction and stops when control is back in here. `used`
 * and `noipa` keep the symbol under its name under LTO (the script looks it up). */
__attribute__((used, noipa)) void replay_batch(fw_ctrl_t *c, const fw_inputs_t *in, int n);
__attribute__((used, noipa)) void replay_batch(fw_ctrl_t *c, const fw_inputs_t *in, int n) {
  fw_outputs_t out;
  void (*step)(fw_ctrl_t *, const fw_inputs_t *, fw_outputs_t *) = g_step;
  for (int k = 0; k < n; k++) {
    step(c, &in[k], &out);
    g_sink += out.duty_abc[0];
  }
}

/* The drive application's two interrupts and its background loop, traced the
 * same way (each through a volatile pointer: the real symbols are entered). */
static fw_app_t g_app;
static fw_adc_inputs_t g_adc[N_MAX];
static void (*volatile g_isr)(void *, const fw_adc_inputs_t *, fw_outputs_t *) = fw_app_isr;
static bool (*volatile g_sup)(void *, fw_outputs_t *) = fw_app_supervise;
static void (*volatile g_bg)(void *) = fw_app_background;
static int g_sup_off; /* periods whose supervision switched the drive off */

/* One period after another as the board runs them: the control interrupt,
 * then the supervision interrupt it pends (it must run before the next control
 * interrupt, or that one latches FW_FAULT_SUPERVISION_MISSED); then bg = 0:
 * the ring is drained as the background would (not counted: `count_isr`,
 * `count_sup`), bg = 1: the real background loop runs once (`count_bg`: the
 * script then counts fw_app_background). */
__attribute__((used, noipa)) void replay_isr_batch(fw_app_t *app, const fw_adc_inputs_t *adc,
                                                   int n, int bg);
__attribute__((used, noipa)) void replay_isr_batch(fw_app_t *app, const fw_adc_inputs_t *adc,
                                                   int n, int bg) {
  fw_outputs_t out;
  void (*isr)(void *, const fw_adc_inputs_t *, fw_outputs_t *) = g_isr;
  bool (*sup)(void *, fw_outputs_t *) = g_sup;
  void (*background)(void *) = g_bg;
  for (int k = 0; k < n; k++) {
    isr(app, &adc[k], &out);
    if (sup(app, &out)) g_sup_off++;
    g_sink += out.duty_abc[0];
    if (bg) {
      background(app);
    } else {
      atomic_store_explicit(&app->ring_tail, atomic_load_explicit(&app->ring_head,
                                                                  memory_order_acquire),
                            memory_order_release);
    }
  }
}

static uint16_t to_counts(float x, float per_count, float offset, uint32_t max) {
  float c = x / per_count + offset;
  if (!(c > 0.0f)) return 0u;
  if (c > (float)max) return (uint16_t)max;
  return (uint16_t)lrintf(c);
}

static int in_run(const fw_ctrl_t *c) {
  return c->phase == FW_START_RUN && fw_fault_code(c) == FW_FAULT_NONE;
}

/* ---- processor-in-the-loop replay ---------------------------------------- */

#define PIL_MAX_EVENTS 64
#define PIL_MAX_WINDOWS 1024
enum { PIL_EV_CONTROLWORD = 0, PIL_EV_MODE = 1, PIL_EV_SPEED_REF = 2, PIL_EV_IQ_REF = 3 };

typedef struct {
  uint32_t step, kind;
  float value;
} pil_event_t;

typedef struct {
  float duty_abc[3];
  float theta_hat_rad;
  uint16_t fault;
  uint8_t pwm_enable, cia402_state;
} pil_out_t;

typedef struct {
  pil_out_t o;
  float speed_hat_mps;
  uint8_t phase, bemf_active, pad[2];
} pil_win_t;

static pil_event_t g_ev[PIL_MAX_EVENTS];
static pil_out_t g_out[N_REC];
static pil_win_t g_wout[N_MAX];
static uint32_t g_hdr[4];
static uint32_t g_win[2 * PIL_MAX_WINDOWS];

/* Reads the windows file KS (uint32 pairs K0, K1); -> number of windows, -1 on error. */
static int pil_windows(const char *path) {
  FILE *f = fopen(path, "rb");
  if (f == NULL) {
    printf("PIL: cannot open %s\n", path);
    return -1;
  }
  size_t n = fread(g_win, 2 * sizeof g_win[0], PIL_MAX_WINDOWS, f);
  fclose(f);
  return (int)n;
}

/* The two halves of a period, each through a volatile pointer: LTO keeps both
 * symbols (the entries the --cycles trace walker looks for) and cannot inline
 * them into pil_period. */
static unsigned (*volatile g_ctl)(fw_ctrl_t *, const fw_inputs_t *, const fw_adc_inputs_t *,
                                  fw_outputs_t *, fw_snapshot_t *) = fw_step_into;
static bool (*volatile g_supv)(fw_ctrl_t *, fw_outputs_t *, fw_snapshot_t *) = fw_supervise;

/* One period as fw_step runs it: the control half, then the supervision half.
 * `used`/`noipa`: the trace walker stops counting a half when the PC is back in
 * here. */
__attribute__((used, noipa)) void pil_period(fw_ctrl_t *c, const fw_inputs_t *in,
                                             fw_outputs_t *out);
__attribute__((used, noipa)) void pil_period(fw_ctrl_t *c, const fw_inputs_t *in,
                                             fw_outputs_t *out) {
  (void)g_ctl(c, in, NULL, out, &c->snap);
  /* not a tail call: fw_supervise must return into here */
  if (g_supv(c, out, &c->snap)) g_sink += 1.0f;
}

/* The events of step k (from event index *e on; events are sorted by step). */
static void pil_events(fw_ctrl_t *c, uint32_t k, uint32_t *e) {
  for (; *e < g_hdr[2] && g_ev[*e].step <= k; (*e)++) {
    if (g_ev[*e].step < k) continue;
    switch (g_ev[*e].kind) {
    case PIL_EV_CONTROLWORD: (void)fw_controlword(c, (uint16_t)g_ev[*e].value); break;
    case PIL_EV_MODE: (void)fw_set_mode(c, (fw_mode_t)(int)g_ev[*e].value); break;
    case PIL_EV_SPEED_REF: (void)fw_set_speed_ref(c, g_ev[*e].value); break;
    default: (void)fw_set_iq_ref(c, g_ev[*e].value); break;
    }
  }
}

static void pil_record(const fw_ctrl_t *c, const fw_outputs_t *out, pil_out_t *o,
                       fw_snapshot_t *snap) {
  fw_get_snapshot(c, snap);
  memcpy(o->duty_abc, out->duty_abc, sizeof out->duty_abc);
  o->theta_hat_rad = snap->theta_hat_rad;
  o->fault = snap->fault_code;
  o->pwm_enable = out->pwm_enable;
  o->cia402_state = snap->cia402_state;
}

/* Reads a PIL trace into g_hdr, g_ev, g_rec; -> the configuration in *cfg. */
static int pil_read(const char *trace, fw_config_t *cfg) {
  FILE *f = fopen(trace, "rb");
  if (f == NULL) {
    printf("PIL: cannot open %s\n", trace);
    return 0;
  }
  uint32_t *hdr = g_hdr;
  int ok = fread(hdr, sizeof g_hdr, 1, f) == 1 && hdr[0] == 0x544C4950u /* "PILT" */ &&
           hdr[1] <= N_REC && hdr[2] <= PIL_MAX_EVENTS && hdr[3] == sizeof(fw_config_t) &&
           fread(cfg, sizeof *cfg, 1, f) == 1 &&
           fread(g_ev, sizeof g_ev[0], hdr[2], f) == hdr[2] &&
           fread(g_rec, sizeof g_rec[0], hdr[1], f) == hdr[1];
  fclose(f);
  if (!ok) {
    printf("PIL: bad trace %s (sizeof(fw_config_t) here %u)\n", trace,
           (unsigned)sizeof *cfg);
  }
  return ok;
}

static int pil_replay(const char *trace, const char *outpath, const char *states,
                      const char *ks) {
  fw_config_t cfg;
  if (!pil_read(trace, &cfg)) return 1;
  int nk = ks != NULL ? pil_windows(ks) : 0;
  if (nk < 0) return 1;
  FILE *sf = NULL;
  if (states != NULL && (sf = fopen(states, "wb")) == NULL) {
    printf("PIL: cannot open %s\n", states);
    return 1;
  }
  fw_init(&g_c, &cfg);
  fw_current_zero_external(&g_c); /* the trace holds the inputs in A: no raw samples */
  uint32_t e = 0;
  int w = 0;
  for (uint32_t k = 0; k < g_hdr[1]; k++) {
    for (; sf != NULL && w < nk && g_win[2 * w] == k; w++) {
      if (fwrite(&g_c, sizeof g_c, 1, sf) != 1) {
        printf("PIL: cannot write %s\n", states);
        return 1;
      }
    }
    pil_events(&g_c, k, &e);
    fw_outputs_t out;
    fw_snapshot_t snap;
    pil_period(&g_c, &g_rec[k], &out);
    pil_record(&g_c, &out, &g_out[k], &snap);
  }
  if (sf != NULL) {
    fclose(sf);
    if (w != nk) {
      printf("PIL: %d of %d states saved (K0 must ascend and be < %u)\n", w, nk,
             (unsigned)g_hdr[1]);
      return 1;
    }
  }
  FILE *o = fopen(outpath, "wb");
  if (o == NULL || fwrite(g_out, sizeof g_out[0], g_hdr[1], o) != g_hdr[1]) {
    printf("PIL: cannot write %s\n", outpath);
    return 1;
  }
  fclose(o);
  printf("PIL: replay ok steps=%u fault=0x%04x\n", (unsigned)g_hdr[1],
         (unsigned)fw_fault_code(&g_c));
  return 0;
}

static int pil_window(const char *trace, const char *states, const char *outpath,
                      const char *ks) {
  fw_config_t cfg;
  if (!pil_read(trace, &cfg)) return 1;
  int nw = pil_windows(ks);
  if (nw < 1) return 1;
  FILE *sf = fopen(states, "rb");
  if (sf == NULL) {
    printf("PIL: cannot open %s\n", states);
    return 1;
  }
  int n = 0;
  for (int w = 0; w < nw; w++) {
    uint32_t k0 = g_win[2 * w], k1 = g_win[2 * w + 1];
    if (k1 <= k0 || k1 > g_hdr[1] || n + (int)(k1 - k0) > N_MAX ||
        fread(&g_c, sizeof g_c, 1, sf) != 1) {
      printf("PIL: bad window %d [%u, %u) (at most %d steps in all) or short state file\n",
             w, (unsigned)k0, (unsigned)k1, N_MAX);
      fclose(sf);
      return 1;
    }
    uint32_t e = 0;
    for (uint32_t k = k0; k < k1; k++, n++) {
      pil_events(&g_c, k, &e);
      fw_outputs_t out;
      fw_snapshot_t snap;
      pil_period(&g_c, &g_rec[k], &out);
      pil_record(&g_c, &out, &g_wout[n].o, &snap);
      g_wout[n].speed_hat_mps = snap.speed_hat_mps;
      g_wout[n].phase = (uint8_t)g_c.phase;
      g_wout[n].bemf_active = snap.bemf_active;
    }
  }
  fclose(sf);
  FILE *o = fopen(outpath, "wb");
  if (o == NULL || fwrite(g_wout, sizeof g_wout[0], (size_t)n, o) != (size_t)n) {
    printf("PIL: cannot write %s\n", outpath);
    return 1;
  }
  fclose(o);
  printf("PIL: window ok windows=%d steps=%d\n", nw, n);
  return 0;
}

int main(int argc, char **argv) {
  if (argc >= 4 && strcmp(argv[1], "replay") == 0) {
    return pil_replay(argv[2], argv[3], argc >= 6 ? argv[4] : NULL, argc >= 6 ? argv[5] : NULL);
  }
  if (argc >= 6 && strcmp(argv[1], "window") == 0) {
    return pil_window(argv[2], argv[3], argv[4], argv[5]);
  }
  if (argc >= 4 && strcmp(argv[1], "warm") == 0) {
    int n = atoi(argv[3]);
    if (n < 1 || n > N_MAX) n = N_MAX;
    int speed_mode = argc >= 5 && strcmp(argv[4], "speed") == 0;
    locked_mover_warm_up(&g_base, speed_mode, g_rec, N_REC);
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
  int bg = argc >= 5 && strcmp(argv[1], "count_bg") == 0;
  int isr = bg || (argc >= 5 && (strcmp(argv[1], "count_isr") == 0 ||
                                 strcmp(argv[1], "count_sup") == 0));
  if (isr || (argc >= 5 && strcmp(argv[1], "count") == 0)) {
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
    const fw_config_t *cfg = &g_base.cfg;
    int period = (int)(cfg->sensing.f_pwm_Hz / cfg->estimator.f_inj_Hz + 0.5f);
    if (period < 1 || batch % period != 0) {
      printf("CM4: batch %d is not a multiple of the injection period %d\n", batch, period);
      return 1;
    }
    fw_ctrl_t *c = &g_c;
    if (isr) { /* the inputs as the ADC delivered them; the core inside the application */
      for (int k = 0; k < batch * nb; k++) {
        for (int j = 0; j < 3; j++) {
          g_adc[k].i_abc_counts[j] =
              to_counts(g_rec[k].i_abc_A[j], cfg->sensing.adc_A_per_count,
                        cfg->sensing.adc_offset_counts, cfg->sensing.adc_max_count);
        }
        g_adc[k].u_dc_counts = to_counts(g_rec[k].u_dc_V, cfg->sensing.adc_V_per_count, 0.0f,
                                         cfg->sensing.adc_max_count);
      }
      if (fw_app_init(&g_app, cfg, 1u) != FW_OK) {
        printf("CM4: fw_app_init refused the configuration\n");
        return 1;
      }
      c = fw_app_ctrl(&g_app);
    }
    int all_run = 1;
    for (int b = 0; b < nb; b++) {
      memcpy(c, &g_base, sizeof *c);
      if (isr) {
        replay_isr_batch(&g_app, &g_adc[b * batch], batch, bg);
      } else {
        replay_batch(c, &g_rec[b * batch], batch);
      }
      const unsigned missed = isr ? (unsigned)g_app.count.sup_missed : 0u;
      if (!in_run(c) || g_sup_off != 0 || missed != 0u) {
        if (all_run) {
          printf("CM4: batch %d left closed loop: phase %d fault 0x%04x, supervision "
                 "switched off in %d periods, missed in %u\n",
                 b, (int)c->phase, (unsigned)fw_fault_code(c), g_sup_off, missed);
        }
        all_run = 0;
      }
    }
    printf("CM4: count done batches=%d batch=%d closed_loop=%s phase=%d fault=0x%04x\n", nb,
           batch, all_run ? "yes" : "NO", (int)c->phase, (unsigned)fw_fault_code(c));
    return all_run ? 0 : 1;
  }
  printf("usage: harness warm STATE N [force|speed] | harness count STATE BATCH NB | "
         "harness count_isr STATE BATCH NB | harness count_sup STATE BATCH NB | "
         "harness count_bg STATE BATCH NB | "
         "harness replay TRACE OUT [STATES KS] | "
         "harness window TRACE STATES OUT KS\n");
  return 2;
}
