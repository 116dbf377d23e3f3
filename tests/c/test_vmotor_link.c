/**
 * @file test_vmotor_link.c
 * @brief The virtual load machine's command line
 *        (sim_fallback/src/sim_vmotor_link.c) on a recording plant written
 *        here (the link uses the plant's public API only: sim_set_load,
 *        sim_set_params, sim_step_count), and its number formatter and
 *        parser against the C library's (snprintf "%.15g", strtod).
 *
 * Checked: each command's reply, word for word; the plant changed only as
 * commanded, only inside the owner's lock, and not at all on an error;
 * ranges (|F| <= 1e6, finite; ref_fault 0 or 1); a line of 81 bytes is
 * refused at once and discarded to its newline, one of 80 accepted; every
 * line gets exactly one reply ending in one "\n"; formatting and parsing
 * agree with the C library over random values.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../sim_fallback/src/sim_vmotor_link.c"
#include "tinytest.h"

/* ---- a recording plant -------------------------------------------------------- */

struct sim_s {
  sim_plant_params_t p;
  double load;
  uint64_t k;
  int loads, param_sets, refuse, unlocked_calls;
  int lock_depth;
};

void sim_set_load(sim_t *s, double F_N) {
  s->loads++;
  if (s->lock_depth == 0)
    s->unlocked_calls++;
  s->load = F_N;
}

int sim_set_params(sim_t *s, const sim_plant_params_t *p, const char **bad_field) {
  s->param_sets++;
  if (s->lock_depth == 0)
    s->unlocked_calls++;
  if (s->refuse) {
    if (bad_field)
      *bad_field = "ref_fault";
    return -37;
  }
  s->p = *p;
  return 0;
}

uint64_t sim_step_count(const sim_t *s) {
  return s->k;
}

static uint32_t lk_enter(void *ctx) {
  sim_t *s = (sim_t *)ctx;
  return (uint32_t)s->lock_depth++;
}
static void lk_exit(void *ctx, uint32_t key) {
  sim_t *s = (sim_t *)ctx;
  s->lock_depth = (int)key;
}

static size_t stats_fn(void *ctx, char *buf, size_t cap) {
  (void)ctx;
  return (size_t)snprintf(buf, cap, "plant=123/456@7");
}

static sim_t g_sim;
static sim_vmotor_link_t g_link;
static volatile uint32_t g_overruns = 7u;

static void setup(void) {
  memset(&g_sim, 0, sizeof g_sim);
  for (size_t i = 0; i < sizeof g_sim.p; i++)
    ((uint8_t *)&g_sim.p)[i] = (uint8_t)(i * 7u + 1u);
  g_sim.p.ref_fault = 0u;
  g_sim.k = 123456789012ull;
  sim_vmotor_lock_t lock = {&g_sim, lk_enter, lk_exit};
  TT_CHECK(sim_vmotor_link_init(&g_link, &g_sim, &g_sim.p, 0.0, &lock) == 0);
  sim_vmotor_link_set_owner(&g_link, &g_overruns, NULL, NULL);
}

/** Send text; the replies concatenated in out, their count returned. */
static int send(const char *text, char *out, size_t cap) {
  int replies = 0;
  size_t used = 0;
  out[0] = '\0';
  for (const char *p = text; *p != '\0'; p++) {
    char r[SIM_VMOTOR_REPLY_MAX];
    size_t n = sim_vmotor_link_push(&g_link, (uint8_t)*p, r, sizeof r);
    if (n > 0) {
      replies++;
      if (r[n - 1] != '\n' || memchr(r, '\n', n - 1) != NULL || strlen(r) != n)
        replies += 1000;
      if (used + n < cap) {
        memcpy(out + used, r, n + 1);
        used += n;
      }
    }
  }
  return replies;
}

static void test_load(void) {
  setup();
  char out[1024];
  TT_CHECK(send("load 2.5\n", out, sizeof out) == 1);
  TT_CHECK(strcmp(out, "ok load 2.5\n") == 0);
  TT_CHECK(g_sim.load == 2.5 && g_sim.loads == 1 && g_sim.unlocked_calls == 0);
  TT_CHECK(send("load -1e6\r\n", out, sizeof out) == 1);
  TT_CHECK(strcmp(out, "ok load -1000000\n") == 0 && g_sim.load == -1e6);
  TT_CHECK(send("  load\t+65.25  \n", out, sizeof out) == 1);
  TT_CHECK(strcmp(out, "ok load 65.25\n") == 0 && g_sim.load == 65.25);
  TT_CHECK(send("load 0.001\n", out, sizeof out) == 1 && strcmp(out, "ok load 0.001\n") == 0);
  const int loads = g_sim.loads;
  const char *bad[] = {"load 1000000.5\n", "load -2e6\n", "load nan\n", "load inf\n",
                       "load 1e400\n",     "load\n",      "load 1 2\n", "load abc\n",
                       "load 1e\n",        "load .\n",    "load --1\n", "load 1.5x\n",
                       "LOAD 1\n"};
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    TT_CHECK(send(bad[i], out, sizeof out) == 1);
    TT_CHECK(strncmp(out, "err ", 4) == 0);
  }
  TT_CHECK(g_sim.loads == loads && g_sim.load == 0.001); /* nothing applied */
  send("load 2e6\n", out, sizeof out);
  TT_CHECK(strstr(out, "|F| <= 1e6") != NULL); /* the range is named */
  send("load abc\n", out, sizeof out);
  TT_CHECK(strstr(out, "'abc'") != NULL && strstr(out, "finite") != NULL);
}

static void test_ref_fault(void) {
  setup();
  char out[1024];
  sim_plant_params_t before = g_sim.p;
  TT_CHECK(send("ref_fault 1\n", out, sizeof out) == 1);
  TT_CHECK(strcmp(out, "ok ref_fault 1\n") == 0);
  TT_CHECK(g_sim.p.ref_fault == 1u && g_sim.unlocked_calls == 0);
  before.ref_fault = 1u;
  TT_CHECK(memcmp(&before, &g_sim.p, sizeof before) == 0); /* nothing else changed */
  TT_CHECK(send("ref_fault 0\n", out, sizeof out) == 1 && strcmp(out, "ok ref_fault 0\n") == 0);
  TT_CHECK(g_sim.p.ref_fault == 0u);
  const int sets = g_sim.param_sets;
  TT_CHECK(send("ref_fault 2\nref_fault\nref_fault 01\nref_fault 1 1\n", out, sizeof out) == 4);
  TT_CHECK(g_sim.param_sets == sets);
  TT_CHECK(strstr(out, "err ref_fault takes 0 (scale healthy) or 1 (signal lost), got '2'") !=
           NULL);
  g_sim.refuse = 1;
  TT_CHECK(send("ref_fault 1\n", out, sizeof out) == 1);
  TT_CHECK(strncmp(out, "err ref_fault: the plant refused", 32) == 0);
  TT_CHECK(g_link.params.ref_fault == 0u); /* not taken */
}

static void test_status_and_stats(void) {
  setup();
  char out[1024];
  send("load 2.5\nref_fault 1\n", out, sizeof out);
  TT_CHECK(send("status\n", out, sizeof out) == 1);
  TT_CHECK(strcmp(out, "ok status periods=123456789012 load=2.5 ref_fault=1 overruns=7\n") == 0);
  TT_CHECK(send("status now\n", out, sizeof out) == 1 && strncmp(out, "err ", 4) == 0);
  TT_CHECK(send("stats\n", out, sizeof out) == 1 && strncmp(out, "err unknown command", 19) == 0);
  sim_vmotor_link_set_owner(&g_link, NULL, stats_fn, NULL);
  TT_CHECK(send("stats\n", out, sizeof out) == 1 && strcmp(out, "ok stats plant=123/456@7\n") == 0);
  TT_CHECK(send("status\n", out, sizeof out) == 1 && strstr(out, " overruns=0\n") != NULL);
}

static void test_lines(void) {
  setup();
  char out[4096], line[200];
  /* 80 bytes: accepted */
  memset(line, ' ', sizeof line);
  memcpy(line, "load 3", 6);
  line[80] = '\n';
  line[81] = '\0';
  TT_CHECK(send(line, out, sizeof out) == 1 && strcmp(out, "ok load 3\n") == 0);
  /* 81 bytes: refused at the 81st, the rest of the line discarded */
  memset(line, ' ', sizeof line);
  memcpy(line, "load 4", 6);
  line[150] = '\n';
  line[151] = '\0';
  int replies = 0;
  size_t at = 0;
  for (size_t i = 0; line[i] != '\0'; i++) {
    char r[SIM_VMOTOR_REPLY_MAX];
    if (sim_vmotor_link_push(&g_link, (uint8_t)line[i], r, sizeof r) > 0) {
      replies++;
      at = i;
      TT_CHECK(strcmp(r, "err line too long (80 bytes max)\n") == 0);
    }
  }
  TT_CHECK(replies == 1 && at == 80);
  TT_CHECK(g_sim.load == 3.0);
  TT_CHECK(send("status\n", out, sizeof out) == 1 && strncmp(out, "ok status", 9) == 0);
  /* empty and unknown lines: one error each, with the usage */
  TT_CHECK(send("\n", out, sizeof out) == 1 && strncmp(out, "err empty line", 14) == 0);
  TT_CHECK(send("foo bar\n", out, sizeof out) == 1);
  TT_CHECK(strcmp(out, "err unknown command 'foo': load <F> (N, finite, |F| <= 1e6), "
                       "ref_fault <0|1>, status\n") == 0);
  /* binary garbage: one reply per newline, printable echo */
  TT_CHECK(send("\x01\xff\x7f\n", out, sizeof out) == 1 && strstr(out, "'?\?\?'") != NULL);
  /* a small reply buffer: cut, still one line */
  char small[16];
  const char *cmd = "status\n";
  size_t n = 0;
  for (const char *p = cmd; *p; p++)
    n = sim_vmotor_link_push(&g_link, (uint8_t)*p, small, sizeof small);
  TT_CHECK(n == 15 && small[14] == '\n' && small[15] == '\0');
}

static void test_format_against_printf(void) {
  char ours[40], ref[40];
  const double fixed[] = {0.0,
                          1.0,
                          -1.0,
                          2.5,
                          1e6,
                          -1e6,
                          0.1,
                          0.001,
                          1e-5,
                          1e-6,
                          123456.789,
                          1e15,
                          999999999999999.0,
                          1e300,
                          -4.9e-324,
                          65.25,
                          1.0 / 3.0};
  int bad = 0;
  uint64_t x = 88172645463325252ull;
  for (int k = 0; k < 200000 + (int)(sizeof fixed / sizeof fixed[0]); k++) {
    double v;
    if (k < (int)(sizeof fixed / sizeof fixed[0])) {
      v = fixed[k];
    } else {
      x ^= x << 13;
      x ^= x >> 7;
      x ^= x << 17;
      if (k % 2) {
        memcpy(&v, &x, sizeof v); /* any bit pattern */
        if (!isfinite(v))
          continue;
      } else { /* a load-like value */
        v = ((double)(x >> 11) * 0x1.0p-53 - 0.5) * pow(10.0, (double)(int)(x % 13u) - 6.0);
      }
    }
    size_t n = sim_vmotor_format_f64(ours, sizeof ours, v);
    snprintf(ref, sizeof ref, "%.15g", v);
    const double a = fabs(v), o = strtod(ours, NULL), r = strtod(ref, NULL);
    const int exact = a == 0.0 || (a >= 1e-8 && a < 1e37); /* the documented range */
    if (n == 0 || strlen(ours) != n || (exact ? o != r : fabs(o - r) > 1e-13 * fabs(r))) {
      if (bad < 5)
        printf("format %.17g: ours %s, printf %s\n", v, ours, ref);
      bad++;
    }
  }
  TT_CHECK(bad == 0);
  TT_CHECK(sim_vmotor_format_f64(ours, sizeof ours, 2.5) == 3 && strcmp(ours, "2.5") == 0);
  TT_CHECK(sim_vmotor_format_f64(ours, sizeof ours, 1e-7) == 5 && strcmp(ours, "1e-07") == 0);
  TT_CHECK(sim_vmotor_format_f64(ours, sizeof ours, (double)NAN) == 3 && strcmp(ours, "nan") == 0);
  TT_CHECK(sim_vmotor_format_f64(ours, sizeof ours, -(double)INFINITY) == 4);
  TT_CHECK(sim_vmotor_format_f64(ours, 3, 2.5) == 0); /* does not fit */
}

static void test_parse_against_strtod(void) {
  int bad = 0, inexact = 0;
  uint64_t x = 0x9E3779B97F4A7C15ull;
  char text[64];
  for (int k = 0; k < 200000; k++) {
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    const int digits = 1 + (int)(x % 15u);
    uint64_t m = (x >> 8) % 1000000000000000ull;
    int n = snprintf(text, sizeof text, "%s%0*llu", (x >> 60) & 1u ? "-" : "", digits,
                     (unsigned long long)(m % (uint64_t)pow(10.0, digits)));
    const int pt = (int)((x >> 32) % (unsigned)(digits + 1));
    if (pt < digits && k % 3) { /* a decimal point somewhere */
      int start = text[0] == '-' ? 1 : 0;
      memmove(text + start + pt + 1, text + start + pt, (size_t)(n - start - pt + 1));
      text[start + pt] = '.';
      n++;
    }
    if (k % 4 == 0)
      n += snprintf(text + n, sizeof text - (size_t)n, "e%d", (int)((x >> 40) % 15u) - 7);
    double ours = 0.0, ref = strtod(text, NULL);
    if (sim_vmotor_parse_f64(text, (size_t)n, &ours) != 0) {
      if (bad < 5)
        printf("parse refused %s\n", text);
      bad++;
    } else if (ours != ref) {
      if (bad < 5)
        printf("parse %s: ours %.17g, strtod %.17g\n", text, ours, ref);
      bad++;
    }
  }
  /* longer mantissas and exponents: within a few units in the last place */
  for (int k = 0; k < 20000; k++) {
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    snprintf(text, sizeof text, "%llu.%llue%d", (unsigned long long)(x >> 1),
             (unsigned long long)(x % 1000003u), (int)(x % 401u) - 200);
    double ours = 0.0, ref = strtod(text, NULL);
    if (sim_vmotor_parse_f64(text, strlen(text), &ours) != 0 ||
        fabs(ours - ref) > 1e-14 * fabs(ref)) {
      inexact++;
    }
  }
  TT_CHECK(bad == 0);
  TT_CHECK(inexact == 0);
  double v;
  const char *refused[] = {"",      "-",    "+",  ".",  "e5",  "1e",  "1e+", "1..2",
                           "1.2.3", "0x10", "1 ", " 1", "inf", "nan", "1,5", "--1"};
  for (size_t i = 0; i < sizeof refused / sizeof refused[0]; i++) {
    TT_CHECK(sim_vmotor_parse_f64(refused[i], strlen(refused[i]), &v) != 0);
  }
  TT_CHECK(sim_vmotor_parse_f64("1e999", 5, &v) == 0 && isinf(v));
  TT_CHECK(sim_vmotor_parse_f64("-0.0", 4, &v) == 0 && v == 0.0 && signbit(v));
  TT_CHECK(sim_vmotor_parse_f64("000123.4500", 11, &v) == 0 && v == 123.45);
}

int main(void) {
  TT_RUN(test_load);
  TT_RUN(test_ref_fault);
  TT_RUN(test_status_and_stats);
  TT_RUN(test_lines);
  TT_RUN(test_format_against_printf);
  TT_RUN(test_parse_against_strtod);
  return TT_SUMMARY();
}
