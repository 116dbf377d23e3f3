/**
 * @file bench_fw_step.c
 * @brief Cost of one control step (fw_step) in closed-loop operation.
 *
 * 1. Drive the core into closed-loop RUN against a locked-mover model with
 *    HF injection, adaptive SOGI (the most expensive extractor), and record
 *    24 000 input samples.
 * 2. Replay them into copies of the controller state and time fw_step in
 *    batches of 1000 (median ns/step over the batches).
 * Usage: bench_fw_step [time|count N]
 *   time     prints the median and quartiles (default)
 *   count N  runs N steps once (for valgrind --tool=callgrind --toggle-collect=fw_step)
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "pmlsm/fw_ctrl.h"
#include "locked_mover.h"

#define N_REC 24000

static fw_inputs_t g_rec[N_REC];

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

static double now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

int main(int argc, char **argv) {
  static fw_ctrl_t base, c;
  locked_mover_warm_up(&base, 0, g_rec, N_REC);
  if (base.phase != FW_START_RUN || fw_fault_code(&base) != FW_FAULT_NONE) {
    fprintf(stderr, "warm-up did not reach closed loop (phase %d, fault 0x%04x)\n",
            (int)base.phase, (unsigned)fw_fault_code(&base));
    return 1;
  }
  fw_outputs_t out;
  volatile float sink = 0.0f;
  if (argc >= 3 && strcmp(argv[1], "count") == 0) {
    long n = atol(argv[2]);
    c = base;
    for (long k = 0; k < n; k++) {
      fw_step(&c, &g_rec[k % N_REC], &out);
      sink += out.duty_abc[0];
    }
    printf("steps %ld\n", n);
    return 0;
  }
  enum { BATCH = 1000, NB = 200 };
  static double per_step[NB];
  for (int b = 0; b < NB; b++) {
    c = base;
    int off = (b * BATCH) % (N_REC - BATCH);
    double t0 = now_ns();
    for (int k = 0; k < BATCH; k++) {
      fw_step(&c, &g_rec[off + k], &out);
      sink += out.duty_abc[0];
    }
    per_step[b] = (now_ns() - t0) / BATCH;
  }
  qsort(per_step, NB, sizeof(double), cmp_double);
  printf("fw_step ns/step: median %.1f  p25 %.1f  p75 %.1f  (batches of %d, n=%d)\n",
         per_step[NB / 2], per_step[NB / 4], per_step[3 * NB / 4], BATCH, NB);
  printf("sizeof(fw_ctrl_t) = %zu bytes\n", sizeof(fw_ctrl_t));
  return 0;
}
