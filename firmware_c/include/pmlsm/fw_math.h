/**
 * @file fw_math.h
 * @brief Control primitives: Clarke/Park transforms, space-vector modulation,
 *        PI regulator with anti-windup, angle wrap, fast sin/cos and atan2.
 *
 * All blocks are pure functions or caller-owned structs (CMSIS-DSP style).
 * float32 only; no globals; no I/O.
 *
 * Conventions
 *  - Clarke is amplitude invariant: a balanced set of peak I gives |i_ab| = I.
 *  - Park rotates alpha/beta into a frame at angle theta (d axis at theta).
 *  - Angles in radians; fw_wrap_pi_f32() maps to [-pi, pi).
 */
#ifndef PMLSM_FW_MATH_H
#define PMLSM_FW_MATH_H

#include <float.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define FW_PI_F32 3.14159265358979f
#define FW_TWO_PI_F32 6.28318530717959f
#define FW_SQRT3_F32 1.73205080756888f
#define FW_INV_SQRT3_F32 0.577350269189626f

/** Two-component vector (alpha/beta or d/q). */
typedef struct {
  float x; /**< alpha or d component */
  float y; /**< beta or q component */
} fw_vec2_f32_t;

/** sin and cos of one angle. */
typedef struct {
  float s;
  float c;
} fw_sincos_f32_t;

/**
 * Fast sin/cos for an MCU: range reduction to [-pi/4, pi/4] plus odd/even
 * minimax polynomials (degree 7 / 8). Valid for any finite angle; for
 * |theta| < 1e4 rad the absolute error is below FW_SINCOS_MAX_ERR.
 * Non-finite input returns s = 0, c = 1.
 */
fw_sincos_f32_t fw_sincos_f32(float theta_rad);

/** Documented bound on |fw_sincos - libm| for |theta| < 1e4 rad (tested). */
#define FW_SINCOS_MAX_ERR 2.0e-6f

/** Largest |d| fw_sincos_add_f32 rotates by; beyond it, a full fw_sincos_f32. */
#define FW_SINCOS_ADD_MAX_RAD 0.125f

/**
 * sin/cos of theta0 + d from sc0 = fw_sincos_f32(theta0): for a small offset
 * (|d| <= FW_SINCOS_ADD_MAX_RAD) a rotation of sc0 by d, with sin d and cos d
 * from their Taylor series to d^5 / d^4 (truncation below 6e-9 there);
 * otherwise fw_sincos_f32(theta0 + d). Costs about a third of a full
 * fw_sincos_f32 on the Cortex-M4F; the control step needs the estimate's
 * sin/cos at the sample and at two instants close to it. Error against libm
 * at theta0 + d for |theta0| < 1e4 rad: below FW_SINCOS_MAX_ERR (tested,
 * test_math.c: 1.7e-7 measured; fw_sincos_f32 alone 9.3e-8).
 */
static inline fw_sincos_f32_t fw_sincos_add_f32(fw_sincos_f32_t sc0, float theta0_rad,
                                                float d_rad);

/**
 * Fast atan2 for an MCU: the angle of the vector (x, y) in [-pi, pi]. The
 * call of fw_atan2_inline_f32 (below; the back-EMF angle, every period above
 * the handover speed, takes it inline). One
 * division and a degree-9 odd polynomial (octant reduction to
 * |t| <= tan(pi/8), cephes atanf minimax coefficients) instead of libm's
 * atanf + atan2f (about 170 cycles on the Cortex-M4F). For finite (x, y)
 * not both zero the absolute error is below FW_ATAN2_MAX_ERR (tested against
 * double atan2). Zeros, infinities, NaN and |x| + |y| beyond FLT_MAX take
 * libm's atan2f (its conventions: atan2(+-0, +0) = +-0, NaN in, NaN out);
 * the result carries y's sign (-0 included), as libm's does.
 */
float fw_atan2_f32(float y, float x);

/** Documented bound on |fw_atan2_f32 - atan2| for finite input (tested). */
#define FW_ATAN2_MAX_ERR 1.0e-6f

/** fw_wrap_pi_f32 for an angle outside [-pi, pi) (any float). */
float fw_wrap_pi_slow_f32(float theta_rad);

/** Wrap an angle into [0, 2 pi). Non-finite input returns 0. */
float fw_wrap_2pi_f32(float theta_rad);

/** Amplitude-invariant Clarke transform from three phase quantities. */
fw_vec2_f32_t fw_clarke_f32(float a, float b, float c);

/** Inverse Clarke: alpha/beta to phase a, b, c (a + b + c = 0). */
void fw_inv_clarke_f32(fw_vec2_f32_t ab, float abc[3]);

/** Park: alpha/beta to d/q at angle with precomputed sin/cos. */
fw_vec2_f32_t fw_park_f32(fw_vec2_f32_t ab, fw_sincos_f32_t sc);

/** Inverse Park: d/q to alpha/beta. */
fw_vec2_f32_t fw_inv_park_f32(fw_vec2_f32_t dq, fw_sincos_f32_t sc);

/**
 * Space-vector modulation (min/max zero-sequence injection, equivalent to
 * symmetric SVPWM) of an alpha/beta voltage command.
 *
 * The command is first limited to the inscribed circle of the hexagon,
 * |u_ab| <= u_dc / sqrt(3), keeping its direction. Duties are in [0, 1].
 *
 * @param u_ab_V     commanded voltage (V)
 * @param u_dc_V     DC-link voltage (V), must be > 0
 * @param duty_abc   output duties, 0..1
 * @param u_ab_out_V the voltage actually realised after limiting (may be NULL)
 * @return true when the command was limited
 */
bool fw_svpwm_f32(fw_vec2_f32_t u_ab_V, float u_dc_V, float duty_abc[3],
                  fw_vec2_f32_t *u_ab_out_V);

/**
 * PI regulator, parallel form u = kp*e + ki*integral(e), with output limits
 * and anti-windup by conditional integration plus back-calculation clamp:
 * the integrator is held inside [out_min, out_max] and is not advanced in
 * the direction that would deepen saturation.
 */
typedef struct {
  float kp;       /**< proportional gain */
  float ki;       /**< integral gain (per second) */
  float out_min;  /**< lower output limit */
  float out_max;  /**< upper output limit */
  float integ;    /**< integrator state (output units) */
  float out;      /**< last output */
  float ki_dt;    /**< ki * dt of the configured time step (fw_pi_set_dt_f32) */
} fw_pi_f32_t;

/** Initialise gains and limits, clear state. */
void fw_pi_init_f32(fw_pi_f32_t *pi, float kp, float ki, float out_min,
                    float out_max);

/** Clear the integrator and the output. */
void fw_pi_reset_f32(fw_pi_f32_t *pi);

/**
 * One PI step: returns the limited output for error e over time step dt_s,
 * and advances the integrator (anti-windup as described above).
 * @param ff feed-forward added before limiting
 */
float fw_pi_step_f32(fw_pi_f32_t *pi, float e, float ff, float dt_s);

/** Configure the fixed time step of fw_pi_step_cfg_f32 (ki * dt_s is
 *  precomputed; call again after changing ki). fw_pi_init_f32 sets dt 0. */
void fw_pi_set_dt_f32(fw_pi_f32_t *pi, float dt_s);


/** Clamp helper. */
static inline float fw_clampf(float x, float lo, float hi) {
  return x < lo ? lo : (x > hi ? hi : x);
}

/** Force inlining where the compiler supports it (-Os leaves small helpers
 *  out of line: fw_isfinite_f32 cost ~140 instructions per step on the M4). */
#if defined(__GNUC__) || defined(__clang__)
#define FW_ALWAYS_INLINE __attribute__((always_inline)) inline
#define FW_NOINLINE __attribute__((noinline))
#else
#define FW_ALWAYS_INLINE inline
#define FW_NOINLINE
#endif

/** Branch hints for the control step's usual path (closed loop, no fault, no
 *  limit reached): GCC then lays that path out straight, without the taken
 *  branches to out-of-line blocks and back it otherwise guesses (each costs a
 *  pipeline refill on the Cortex-M4). Code layout only: the same results. */
#if defined(__GNUC__) || defined(__clang__)
#define FW_LIKELY(x) __builtin_expect(!!(x), 1)
#define FW_UNLIKELY(x) __builtin_expect(!!(x), 0)
#else
#define FW_LIKELY(x) (x)
#define FW_UNLIKELY(x) (x)
#endif

/** The control interrupt's functions outside the sources the Cortex-M4F image
 *  compiles at -O2 (firmware_c/CMakeLists.txt, PMLSM_CM4_FAST_SOURCES): the
 *  same level, so that the core's code is inlined into them (GCC does not
 *  inline across optimisation levels). ARM GCC only; elsewhere nothing. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__arm__) && defined(__OPTIMIZE_SIZE__)
#define FW_ISR_OPT __attribute__((optimize("O2")))
#else
#define FW_ISR_OPT
#endif

/** fw_clampf(x, -lim, lim), the same result for every x and lim (NaN and a
 *  negative lim included): |x| <= lim implies -lim <= x <= lim, so the usual
 *  in-range value costs one compare instead of two (FPv4 has no VMAXNM/VMINNM;
 *  every compare is a VCMP and a VMRS). */
static FW_ALWAYS_INLINE float fw_clamp_symf(float x, float lim) {
  return FW_LIKELY(fabsf(x) <= lim) ? x : fw_clampf(x, -lim, lim);
}

/* sin/cos constants (fw_sincos_f32, fw_math.c: the range reduction). */
#define FW_PIO2_1 1.5703125f                  /* pi/2 high part, exact */
#define FW_PIO2_2 4.837512969970703125e-4f    /* pi/2 middle part, exact */
#define FW_PIO2_3 7.54978995489188216e-8f     /* pi/2 low part */
#define FW_TWO_OVER_PI 0.636619772367581343f  /* 2/pi */
/* Fast path: |theta| <= 8192 rad (|k| <= 5216 < 2^13, the reduction is as
 * exact as the general one). y + 1.5 * 2^23 - 1.5 * 2^23 rounds y (|y| < 2^22)
 * to the nearest integer in two additions, no compare, no clamp (ties go to
 * even; either neighbour leaves |r| <= pi/4). */
#define FW_SINCOS_FAST_MAX 8192.0f
#define FW_SINCOS_ROUND 12582912.0f /* 1.5 * 2^23 */

/** The polynomials and the quadrant of fw_sincos_f32: sin/cos of k pi/2 + r
 *  for the reduced angle r (|r| <= ~pi/4) and the quadrant k (an integer in
 *  float). */
static FW_ALWAYS_INLINE fw_sincos_f32_t fw_sincos_poly_f32(float r, float kf) {
  const uint32_t quad = (uint32_t)(int32_t)kf & 3u; /* k mod 4, two's complement */
  const float z = r * r;
  const float s = r + r * z * (-1.6666654611e-1f +
                               z * (8.3321608736e-3f + z * -1.9515295891e-4f));
  const float c = 1.0f - 0.5f * z +
                  z * z * (4.166664568298827e-2f +
                           z * (-1.388731625493765e-3f + z * 2.443315711809948e-5f));
  /* quadrant without a jump table: swap for odd k, sin negative for k = 2, 3
   * (mod 4), cos negative for k = 1, 2 */
  const bool swap = (quad & 1u) != 0u;
  const float sv = swap ? c : s;
  const float cv = swap ? s : c;
  fw_sincos_f32_t out;
  out.s = (quad & 2u) != 0u ? -sv : sv;
  out.c = ((quad + 1u) & 2u) != 0u ? -cv : cv;
  return out;
}

/** fw_sincos_f32 with its fast path (|theta| <= FW_SINCOS_FAST_MAX) inline and
 *  the rest a call: the same results. For the step's one full sin/cos per
 *  period (a call cost a stack frame, the pair's moves and two changes of flow). */
static FW_ALWAYS_INLINE fw_sincos_f32_t fw_sincos_fast_f32(float theta_rad) {
  if (fabsf(theta_rad) <= FW_SINCOS_FAST_MAX) { /* false for NaN */
    const float kf = (theta_rad * FW_TWO_OVER_PI + FW_SINCOS_ROUND) - FW_SINCOS_ROUND;
    const float r = ((theta_rad - kf * FW_PIO2_1) - kf * FW_PIO2_2) - kf * FW_PIO2_3;
    return fw_sincos_poly_f32(r, kf);
  }
  return fw_sincos_f32(theta_rad);
}

/* fw_sincos_add_f32 (declared above) inline: the step calls it twice, and a call
 * returning the pair cost a stack frame, the pair's moves and two changes of flow
 * per call on the M4 (-Os keeps it out of line unless forced). */
static FW_ALWAYS_INLINE fw_sincos_f32_t fw_sincos_add_f32(fw_sincos_f32_t sc0, float theta0_rad,
                                                          float d_rad) {
  if (!(fabsf(d_rad) <= FW_SINCOS_ADD_MAX_RAD)) { /* also NaN */
    return fw_sincos_f32(theta0_rad + d_rad);
  }
  const float d2 = d_rad * d_rad;
  const float sd = d_rad + d_rad * d2 * (-1.6666667e-1f + d2 * 8.3333333e-3f);
  const float cd = 1.0f + d2 * (-0.5f + d2 * 4.1666668e-2f);
  fw_sincos_f32_t out;
  out.s = sc0.s * cd + sc0.c * sd;
  out.c = sc0.c * cd - sc0.s * sd;
  return out;
}

/* Angle wrap (fw_math.c, and one turn inline below): 2 pi in two parts,
 * FW_TWO_PI_1 with 8 significant bits, so n * FW_TWO_PI_1 is exact for
 * |n| < 2^16. */
#define FW_TWO_PI_1 6.28125f
#define FW_TWO_PI_2 1.9353071795864769e-3f
/** fw_wrap_pi_f32 subtracts one turn inline for pi <= |theta| < this (a
 *  difference of two wrapped angles reaches 2 pi; floor((theta + pi) / 2 pi)
 *  is +-1 up to here, 2.5 pi, with room to spare). */
#define FW_WRAP_TURN_MAX 8.0f

/** Wrap an angle into [-pi, pi). Non-finite input returns 0. Inline: the
 *  usual angle is already in range (one compare, no call), and an angle one
 *  turn out (pi <= |theta| < FW_WRAP_TURN_MAX: an estimate stepping past +-pi
 *  once per electrical revolution, or the difference of two estimates across
 *  it) loses that turn without a call. There floor((theta + pi) / 2 pi) is
 *  +-1, so theta -+ 2 pi in the two parts of 2 pi is the general wrap's
 *  value before its corrections, which leave a value inside
 *  [-pi, pi) as it is: the same result, bit for bit (test_math.c checks every
 *  float of that range). */
static FW_ALWAYS_INLINE float fw_wrap_pi_f32(float theta_rad) {
  /* |theta| < pi: one constant and one compare */
  if (FW_LIKELY(fabsf(theta_rad) < FW_PI_F32)) {
    return theta_rad;
  }
  /* -pi is in range as it is; NaN, inf, the far angles and a result that
   * needs a correction take the call */
  if (fabsf(theta_rad) < FW_WRAP_TURN_MAX && theta_rad != -FW_PI_F32) {
    const bool pos = theta_rad > 0.0f;
    const float r = (theta_rad - (pos ? FW_TWO_PI_1 : -FW_TWO_PI_1)) -
                    (pos ? FW_TWO_PI_2 : -FW_TWO_PI_2);
    if (FW_LIKELY(fabsf(r) < FW_PI_F32)) {
      return r;
    }
  }
  return fw_wrap_pi_slow_f32(theta_rad);
}

/* ---- atan2 ----------------------------------------------------------------
 * With lo = min(|x|, |y|) and hi = max: atan(lo/hi) in [0, pi/4]. Beyond
 * tan(pi/8), atan(lo/hi) = pi/4 + atan((lo - hi)/(lo + hi)), so the
 * polynomial's argument stays within |t| <= tan(pi/8) with one division on
 * either side (lo - hi is exact for lo >= hi/2, Sterbenz). The polynomial is
 * cephes atanf's (odd, degree 9, relative error ~2e-7 on that interval); the
 * octant is restored by pi/2 - r (|y| > |x|), pi - r (x < 0) and y's sign.
 * Measured (test_math.c) against double atan2: see FW_ATAN2_MAX_ERR. */
#define FW_TAN_PI_8 0.414213562373095f
#define FW_PI_4_F32 0.785398163397448f
#define FW_PI_2_F32 1.57079632679490f

/** fw_atan2_f32 inline (the same function: fw_atan2_f32 calls this). */
static FW_ALWAYS_INLINE float fw_atan2_inline_f32(float y, float x) {
  const float ax = fabsf(x), ay = fabsf(y);
  const float sum = ax + ay;
  if (FW_UNLIKELY(!(sum > 0.0f && sum <= FLT_MAX))) {
    return atan2f(y, x); /* (0, 0), NaN, infinities, overflow: libm's conventions */
  }
  const bool swap = ay > ax;
  const float lo = swap ? ax : ay;
  const float hi = swap ? ay : ax;
  float num = lo, den = hi, r = 0.0f;
  if (lo > FW_TAN_PI_8 * hi) {
    num = lo - hi;
    den = lo + hi;
    r = FW_PI_4_F32;
  }
  const float t = num / den;
  const float z = t * t;
  r += (((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z -
        3.33329491539e-1f) * z * t + t;
  if (swap) {
    r = FW_PI_2_F32 - r;
  }
  if (x < 0.0f) {
    r = FW_PI_F32 - r;
  }
  return copysignf(r, y); /* r >= 0; y's sign, -0 included, as libm */
}

/** True for a finite float (not NaN, not inf), without libm: x - x is 0 for
 *  a finite x and NaN for NaN and +-inf (one subtraction, one compare). To
 *  test several values at once, add their differences: one NaN makes the sum
 *  NaN. */
static FW_ALWAYS_INLINE bool fw_isfinite_f32(float x) {
  return x - x == 0.0f;
}

/** The limit of fw_pi_core_lim_f32: symmetric limits (out_min = -out_max) take
 *  fw_clamp_symf, the same values with one compare on the usual path. */
static FW_ALWAYS_INLINE float fw_pi_clamp_f32(float x, float out_min, float out_max, bool sym) {
  return sym ? fw_clamp_symf(x, out_max) : fw_clampf(x, out_min, out_max);
}

/** PI step (see fw_pi_step_f32) once e, ff are known finite and di = ki e dt
 *  is formed; sym (a constant) when out_min = -out_max. */
static FW_ALWAYS_INLINE float fw_pi_core_lim_f32(fw_pi_f32_t *pi, float e, float ff, float di,
                                                 float out_min, float out_max, bool sym) {
  const float p = pi->kp * e;
  const float integ0 = pi->integ;
  float integ = integ0 + di;
  const float u_try = p + integ + ff;
  if (sym && FW_LIKELY(fabsf(u_try) <= out_max && fabsf(integ) <= out_max)) {
    /* the usual period, inside the limits: no anti-windup (u_try is within
     * [out_min, out_max] = [-out_max, out_max]), the integrator unclamped and the
     * output p + integ + ff is u_try itself. The same results as below with two
     * compares instead of four. */
    pi->integ = integ;
    pi->out = u_try;
    return u_try;
  }
  if (FW_UNLIKELY(u_try > out_max && di > 0.0f)) {
    const float i_lim = out_max - p - ff;
    integ = i_lim > integ0 ? i_lim : integ0; /* max */
  } else if (FW_UNLIKELY(u_try < out_min && di < 0.0f)) {
    const float i_lim = out_min - p - ff;
    integ = i_lim < integ0 ? i_lim : integ0; /* min */
  }
  integ = fw_pi_clamp_f32(integ, out_min, out_max, sym);
  pi->integ = integ;
  const float out = fw_pi_clamp_f32(p + integ + ff, out_min, out_max, sym);
  pi->out = out;
  return out;
}

/** PI step (see fw_pi_step_f32) once e, ff are known finite and di = ki e dt
 *  is formed. */
static FW_ALWAYS_INLINE float fw_pi_core_f32(fw_pi_f32_t *pi, float e, float ff, float di,
                                             float out_min, float out_max) {
  return fw_pi_core_lim_f32(pi, e, ff, di, out_min, out_max, false);
}

/**
 * The same step over the configured time step (fw_pi_set_dt_f32) with
 * symmetric output limits +-lim given per call (out_min/out_max are not
 * used and not updated): the integral increment is (ki dt) e instead of
 * ki e dt (rounding may differ in the last bit). Non-finite e or ff leave the
 * state alone and return the last output. Inline (a call per current axis
 * cost ~10 instructions on the M4).
 */
static FW_ALWAYS_INLINE float fw_pi_step_cfg_f32(fw_pi_f32_t *pi, float e, float ff, float lim) {
  const float nf = (e - e) + (ff - ff); /* 0 when both are finite, else NaN */
  if (!(nf == 0.0f)) {
    return pi->out;
  }
  return fw_pi_core_lim_f32(pi, e, ff, pi->ki_dt * e, -lim, lim, true);
}

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_MATH_H */
