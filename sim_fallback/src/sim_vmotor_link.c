/*
 * The virtual load machine's command line (sim_vmotor_link.h): a line parser
 * over the public plant API, and the small number formatter and parser it
 * needs (an MCU image has neither printf's floating point nor a strtod that
 * does not allocate).
 */
#include <math.h>
#include <string.h>

/* relative: the unit test includes this file without the simulator's include path */
#include "../include/sim_vmotor_link.h"

#define USAGE "load <F> (N, finite, |F| <= 1e6), ref_fault <0|1>, status"

/* ---- numbers ----------------------------------------------------------------- */

/** 10^k; exact for 0 <= k <= 22 (every factor and product is a double). */
static double pow10_of(int k) {
  double r = 1.0, b = 10.0;
  unsigned n = (unsigned)(k < 0 ? -k : k);
  while (n != 0u) {
    if (n & 1u) {
      r *= b;
    }
    b *= b;
    n >>= 1;
  }
  return k < 0 ? 1.0 / r : r;
}

/** x * 10^k: one rounding when |k| <= 22, a few more beyond. */
static double scale10(double x, int k) {
  for (; k > 22; k -= 22) {
    x *= 1e22;
  }
  for (; k < -22; k += 22) {
    x /= 1e22;
  }
  return k >= 0 ? x * pow10_of(k) : x / pow10_of(-k);
}

int sim_vmotor_parse_f64(const char *text, size_t len, double *v) {
  if (text == NULL || v == NULL) {
    return -1;
  }
  size_t i = 0u;
  int neg = 0;
  if (i < len && (text[i] == '+' || text[i] == '-')) {
    neg = text[i] == '-';
    i++;
  }
  uint64_t m = 0u; /* the first 19 significant digits */
  int sig = 0, e10 = 0, digits = 0, point = 0;
  for (; i < len; i++) {
    const char c = text[i];
    if (c == '.' && !point) {
      point = 1;
      continue;
    }
    if (c < '0' || c > '9') {
      break;
    }
    digits++;
    if (m == 0u && c == '0') {
      if (point) {
        e10--; /* leading zero after the point */
      }
      continue;
    }
    if (sig < 19) {
      m = m * 10u + (uint64_t)(c - '0');
      sig++;
      if (point) {
        e10--;
      }
    } else if (!point) {
      e10++; /* digits beyond the 19th only scale */
    }
  }
  if (digits == 0) {
    return -1;
  }
  if (i < len && (text[i] == 'e' || text[i] == 'E')) {
    i++;
    int eneg = 0, edigits = 0;
    long ex = 0;
    if (i < len && (text[i] == '+' || text[i] == '-')) {
      eneg = text[i] == '-';
      i++;
    }
    for (; i < len && text[i] >= '0' && text[i] <= '9'; i++) {
      if (ex < 100000) {
        ex = ex * 10 + (text[i] - '0');
      }
      edigits++;
    }
    if (edigits == 0) {
      return -1;
    }
    e10 += (int)(eneg ? -ex : ex);
  }
  if (i != len) {
    return -1; /* trailing characters */
  }
  double x;
  if (m == 0u) {
    x = 0.0;
  } else if (e10 > 400) {
    x = (double)INFINITY;
  } else if (e10 < -400) {
    x = 0.0;
  } else {
    x = scale10((double)m, e10);
  }
  *v = neg ? -x : x;
  return 0;
}

/** p + e = a * b exactly (Dekker's product with Veltkamp's split; no fma, no overflow
 *  for the magnitudes used here). */
static void two_prod(double a, double b, double *p, double *e) {
  const double ca = 134217729.0 * a, cb = 134217729.0 * b; /* 2^27 + 1 */
  const double ah = ca - (ca - a), al = a - ah, bh = cb - (cb - b), bl = b - bh;
  *p = a * b;
  *e = ((ah * bh - *p) + ah * bl + al * bh) + al * bl;
}

/** a * 10^k (a > 0, result below 2^53) rounded to the nearest integer, ties to even,
 *  and its floor in *fl: exact for |k| <= 22 (the product's rounding error is known
 *  exactly). */
static uint64_t scaled_round(double a, int k, uint64_t *fl) {
  double y, err = 0.0;
  if (k >= 0 && k <= 22) {
    two_prod(a, pow10_of(k), &y, &err);
  } else if (k < 0 && k >= -22) {
    const double P = pow10_of(-k);
    double p, e;
    y = a / P;
    two_prod(y, P, &p, &e);
    err = ((a - p) - e) / P; /* a - y P exactly, over P: its sign is exact */
  } else {
    y = scale10(a, k);
  }
  const double d = floor(y), t = y - d; /* t: a multiple of ulp(y), |err| <= ulp(y) / 2 */
  const uint64_t u = (uint64_t)d;
  *fl = (t == 0.0 && err < 0.0 && u > 0u) ? u - 1u : u;
  const int up = t > 0.5 || (t == 0.5 && (err > 0.0 || (err == 0.0 && (u & 1u) != 0u)));
  return up ? u + 1u : u;
}

/** Decimal digits of u into buf (most significant first); returns the count. */
static size_t u64_digits(uint64_t u, char *buf) {
  char tmp[20];
  size_t n = 0u;
  do {
    tmp[n++] = (char)('0' + (int)(u % 10u));
    u /= 10u;
  } while (u != 0u);
  for (size_t k = 0u; k < n; k++) {
    buf[k] = tmp[n - 1u - k];
  }
  return n;
}

size_t sim_vmotor_format_f64(char *buf, size_t cap, double v) {
  char out[40];
  size_t n = 0u;
  if (buf == NULL || cap == 0u) {
    return 0u;
  }
  if (isnan(v)) {
    memcpy(out, "nan", 3u);
    n = 3u;
  } else {
    if (signbit(v) && v != 0.0) {
      out[n++] = '-';
    }
    const double a = fabs(v);
    if (isinf(a)) {
      memcpy(&out[n], "inf", 3u);
      n += 3u;
    } else if (a == 0.0) {
      out[n++] = '0';
    } else {
      /* 15 significant digits: d = round(a * 10^(14 - e)) in [1e14, 1e15) */
      int e = (int)floor(log10(a));
      uint64_t fl, d = scaled_round(a, 14 - e, &fl);
      for (int tries = 0; tries < 2; tries++) { /* log10 may be one off: 10^e <= a exactly */
        if (fl >= 1000000000000000u) {
          e++;
        } else if (fl < 100000000000000u) {
          e--;
        } else {
          break;
        }
        d = scaled_round(a, 14 - e, &fl);
      }
      if (d >= 1000000000000000u) { /* rounded up to the next power of ten */
        d = 100000000000000u;
        e++;
      }
      char dig[20];
      size_t nd = u64_digits(d, dig);
      while (nd > 1u && dig[nd - 1u] == '0') {
        nd--;
      }
      if (e >= -5 && e < 15) { /* fixed */
        if (e < 0) {
          out[n++] = '0';
          out[n++] = '.';
          for (int k = -1; k > e; k--) {
            out[n++] = '0';
          }
          memcpy(&out[n], dig, nd);
          n += nd;
        } else {
          const size_t ip = (size_t)e + 1u; /* integer digits */
          for (size_t k = 0u; k < ip; k++) {
            out[n++] = k < nd ? dig[k] : '0';
          }
          if (nd > ip) {
            out[n++] = '.';
            memcpy(&out[n], &dig[ip], nd - ip);
            n += nd - ip;
          }
        }
      } else { /* d.ddde+XX */
        out[n++] = dig[0];
        if (nd > 1u) {
          out[n++] = '.';
          memcpy(&out[n], &dig[1], nd - 1u);
          n += nd - 1u;
        }
        out[n++] = 'e';
        out[n++] = e < 0 ? '-' : '+';
        const unsigned ae = (unsigned)(e < 0 ? -e : e);
        if (ae < 10u) {
          out[n++] = '0';
        }
        n += u64_digits(ae, &out[n]);
      }
    }
  }
  if (n + 1u > cap) {
    buf[0] = '\0';
    return 0u;
  }
  memcpy(buf, out, n);
  buf[n] = '\0';
  return n;
}

/* ---- replies ------------------------------------------------------------------- */

/** A reply being written: text is cut at cap - 2 bytes, "\n" always ends it. */
typedef struct {
  char *buf;
  size_t cap, n;
} reply_t;

static void put(reply_t *r, const char *s, size_t len) {
  for (size_t k = 0u; k < len && r->n + 2u < r->cap; k++) {
    r->buf[r->n++] = s[k];
  }
}

static void put_str(reply_t *r, const char *s) {
  put(r, s, strlen(s));
}

static void put_u64(reply_t *r, uint64_t u) {
  char d[20];
  put(r, d, u64_digits(u, d));
}

static void put_f64(reply_t *r, double v) {
  char d[40];
  put(r, d, sim_vmotor_format_f64(d, sizeof d, v));
}

/** A token of the host's line, quoted, non-printable bytes as '?', at most 24 bytes. */
static void put_token(reply_t *r, const char *s, size_t len) {
  put(r, "'", 1u);
  for (size_t k = 0u; k < len && k < 24u; k++) {
    const char c = (s[k] >= 0x20 && s[k] <= 0x7E) ? s[k] : '?';
    put(r, &c, 1u);
  }
  if (len > 24u) {
    put_str(r, "...");
  }
  put(r, "'", 1u);
}

static size_t finish(reply_t *r) {
  if (r->cap == 0u) {
    return 0u;
  }
  if (r->cap == 1u) {
    r->buf[0] = '\0';
    return 0u;
  }
  r->buf[r->n++] = '\n';
  r->buf[r->n] = '\0';
  return r->n;
}

/* ---- the link ------------------------------------------------------------------ */

int sim_vmotor_link_init(sim_vmotor_link_t *l, sim_t *sim, const sim_plant_params_t *params,
                         double load_N, const sim_vmotor_lock_t *lock) {
  if (l == NULL || sim == NULL || params == NULL) {
    return -1;
  }
  memset(l, 0, sizeof *l);
  l->sim = sim;
  l->params = *params;
  l->load_N = load_N;
  if (lock != NULL) {
    l->lock = *lock;
  }
  return 0;
}

void sim_vmotor_link_set_owner(sim_vmotor_link_t *l, const volatile uint32_t *overruns,
                               sim_vmotor_stats_fn fn, void *ctx) {
  if (l != NULL) {
    l->overruns = overruns;
    l->stats = fn;
    l->stats_ctx = ctx;
  }
}

size_t sim_vmotor_link_sizeof(void) {
  return sizeof(sim_vmotor_link_t);
}

static uint32_t lock_enter(const sim_vmotor_link_t *l) {
  return l->lock.enter != NULL ? l->lock.enter(l->lock.ctx) : 0u;
}

static void lock_exit(const sim_vmotor_link_t *l, uint32_t key) {
  if (l->lock.exit != NULL) {
    l->lock.exit(l->lock.ctx, key);
  }
}

static int is_space(char c) {
  return c == ' ' || c == '\t';
}

/** Split the line into at most 3 tokens; returns the count (3: more than two). */
static unsigned tokens(const char *s, size_t len, const char *tok[3], size_t tlen[3]) {
  unsigned n = 0u;
  size_t i = 0u;
  while (n < 3u) {
    while (i < len && is_space(s[i])) {
      i++;
    }
    if (i >= len) {
      break;
    }
    const size_t b = i;
    while (i < len && !is_space(s[i])) {
      i++;
    }
    tok[n] = &s[b];
    tlen[n] = i - b;
    n++;
  }
  return n;
}

static int token_is(const char *t, size_t len, const char *word) {
  return len == strlen(word) && memcmp(t, word, len) == 0;
}

static void do_line(sim_vmotor_link_t *l, reply_t *r) {
  const char *tok[3] = {NULL, NULL, NULL};
  size_t tl[3] = {0u, 0u, 0u};
  const unsigned nt = tokens(l->line, l->len, tok, tl);
  int ok = 0;
  if (nt == 0u) {
    put_str(r, "err empty line: " USAGE);
  } else if (token_is(tok[0], tl[0], "load")) {
    double f = 0.0;
    if (nt != 2u || sim_vmotor_parse_f64(tok[1], tl[1], &f) != 0) {
      put_str(r, "err load takes one number: load <F> (N, finite, |F| <= 1e6)");
      if (nt >= 2u) {
        put_str(r, ", got ");
        put_token(r, tok[1], tl[1]);
      }
    } else if (!isfinite(f) || fabs(f) > SIM_VMOTOR_LOAD_MAX_N) {
      put_str(r, "err load ");
      put_token(r, tok[1], tl[1]);
      put_str(r, " out of range: finite, |F| <= 1e6 N");
    } else {
      const uint32_t key = lock_enter(l);
      sim_set_load(l->sim, f);
      lock_exit(l, key);
      l->load_N = f;
      put_str(r, "ok load ");
      put_f64(r, f);
      ok = 1;
    }
  } else if (token_is(tok[0], tl[0], "ref_fault")) {
    if (nt != 2u || !(token_is(tok[1], tl[1], "0") || token_is(tok[1], tl[1], "1"))) {
      put_str(r, "err ref_fault takes 0 (scale healthy) or 1 (signal lost)");
      if (nt >= 2u) {
        put_str(r, ", got ");
        put_token(r, tok[1], tl[1]);
      }
    } else {
      sim_plant_params_t p = l->params;
      p.ref_fault = tok[1][0] == '1' ? 1u : 0u;
      const char *bad = NULL;
      const uint32_t key = lock_enter(l);
      const int rc = sim_set_params(l->sim, &p, &bad);
      lock_exit(l, key);
      if (rc != 0) {
        put_str(r, "err ref_fault: the plant refused its parameters (");
        put_str(r, bad != NULL ? bad : "?");
        put_str(r, ")");
      } else {
        l->params = p;
        put_str(r, "ok ref_fault ");
        put_u64(r, p.ref_fault);
        ok = 1;
      }
    }
  } else if (token_is(tok[0], tl[0], "status") && nt == 1u) {
    const uint32_t key = lock_enter(l);
    const uint64_t periods = sim_step_count(l->sim);
    lock_exit(l, key);
    put_str(r, "ok status periods=");
    put_u64(r, periods);
    put_str(r, " load=");
    put_f64(r, l->load_N);
    put_str(r, " ref_fault=");
    put_u64(r, l->params.ref_fault);
    put_str(r, " overruns=");
    put_u64(r, l->overruns != NULL ? *l->overruns : 0u);
    ok = 1;
  } else if (token_is(tok[0], tl[0], "stats") && nt == 1u && l->stats != NULL) {
    char s[SIM_VMOTOR_REPLY_MAX];
    size_t n = l->stats(l->stats_ctx, s, sizeof s);
    put_str(r, "ok stats ");
    put(r, s, n < sizeof s ? n : sizeof s);
    ok = 1;
  } else if (token_is(tok[0], tl[0], "status")) {
    put_str(r, "err status takes no argument");
  } else {
    put_str(r, "err unknown command ");
    put_token(r, tok[0], tl[0]);
    put_str(r, ": " USAGE);
  }
  if (ok) {
    l->lines_ok++;
  } else {
    l->lines_err++;
  }
}

size_t sim_vmotor_link_push(sim_vmotor_link_t *l, uint8_t byte, char *reply, size_t cap) {
  if (l == NULL || reply == NULL || cap == 0u) {
    return 0u;
  }
  reply_t r = {reply, cap, 0u};
  if (byte == (uint8_t)'\r') {
    return 0u;
  }
  if (byte == (uint8_t)'\n') {
    if (l->discard) {
      l->discard = 0u;
      l->len = 0u;
      return 0u; /* answered when it became too long */
    }
    do_line(l, &r);
    l->len = 0u;
    return finish(&r);
  }
  if (l->discard) {
    return 0u;
  }
  if (l->len >= SIM_VMOTOR_LINE_MAX) {
    l->discard = 1u;
    l->lines_err++;
    put_str(&r, "err line too long (80 bytes max)");
    return finish(&r);
  }
  l->line[l->len++] = (char)byte;
  return 0u;
}
