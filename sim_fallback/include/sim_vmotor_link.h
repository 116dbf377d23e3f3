/**
 * @file sim_vmotor_link.h
 * @brief The virtual load machine's command line: test equipment of an
 *        emulated rig (the emulated board's third UART), not part of the
 *        drive. It acts on the virtual motor (a sim_t) as a load machine
 *        and a scale-cable puller would on a real rig.
 *
 * ASCII lines ending in "\n" (a "\r" anywhere is ignored); every line gets
 * exactly one reply line:
 *
 *     load <F>           external load force F in N (finite, |F| <= 1e6),
 *                        opposing +x (sim_set_load)      -> "ok load <F>"
 *     ref_fault <0|1>    the reference scale's signal lost (1) or back (0)
 *                        (sim_set_params, ref_fault)     -> "ok ref_fault <n>"
 *     status             -> "ok status periods=<n> load=<F> ref_fault=<n> overruns=<n>"
 *                        (plant periods integrated, load in N, scale fault,
 *                        the owner's overrun count)
 *     stats              -> "ok stats <text>" when the owner gave a stats
 *                        callback (the emulated board: its timing figures)
 *     anything else      -> "err <what>, with the allowed form or range>"
 *     over 80 bytes      -> "err line too long (80 bytes max)" at once; the
 *                        rest of the line up to its "\n" is discarded
 *
 * Numbers are written by sim_vmotor_format_f64 (no printf: an MCU image
 * without printf's floating point) and read by sim_vmotor_parse_f64 (no
 * strtod: newlib's allocates).
 *
 * The plant is shared with the interrupt that steps it: the link changes it
 * only inside the owner's lock (sim_vmotor_lock_t, e.g. interrupts masked).
 * No globals; the state is the caller's sim_vmotor_link_t.
 */
#ifndef PMLSM_SIM_VMOTOR_LINK_H
#define PMLSM_SIM_VMOTOR_LINK_H

#include <stddef.h>
#include <stdint.h>

#include "pmlsm_sim.h"

#ifdef __cplusplus
extern "C" {
#endif

#define SIM_VMOTOR_LINE_MAX 80u     /**< longest line (bytes before its "\n", "\r" not counted) */
#define SIM_VMOTOR_REPLY_MAX 512u   /**< longest reply, "\n" included */
#define SIM_VMOTOR_LOAD_MAX_N 1.0e6 /**< |load| limit (N) */

/** The owner's lock around changes of the plant (enter returns the key for exit). */
typedef struct {
  void *ctx;
  uint32_t (*enter)(void *ctx);
  void (*exit)(void *ctx, uint32_t key);
} sim_vmotor_lock_t;

/** Extra figures of the owner for "stats": writes at most cap bytes, returns the count. */
typedef size_t (*sim_vmotor_stats_fn)(void *ctx, char *buf, size_t cap);

/** Link state, caller-owned. Treat the members as private. */
typedef struct {
  sim_t *sim;
  sim_plant_params_t params; /**< the plant's parameters as last set through the link */
  double load_N;             /**< the load as last set */
  sim_vmotor_lock_t lock;
  const volatile uint32_t *overruns; /**< the owner's overrun count (NULL: 0) */
  sim_vmotor_stats_fn stats;
  void *stats_ctx;
  char line[SIM_VMOTOR_LINE_MAX];
  uint32_t len;
  uint32_t discard; /**< a too long line: dropping bytes up to its "\n" */
  uint32_t lines_ok, lines_err;
} sim_vmotor_link_t;

/**
 * Bind a link to a plant created with params (copied: ref_fault changes
 * are made on this copy) and whose load is load_N. lock may be NULL (no
 * concurrent stepping). Returns 0, or -1 on a NULL argument.
 */
int sim_vmotor_link_init(sim_vmotor_link_t *l, sim_t *sim, const sim_plant_params_t *params,
                         double load_N, const sim_vmotor_lock_t *lock);

/** Show *overruns in "status" (NULL: 0), and answer "stats" with fn (NULL: no stats). */
void sim_vmotor_link_set_owner(sim_vmotor_link_t *l, const volatile uint32_t *overruns,
                               sim_vmotor_stats_fn fn, void *ctx);

/**
 * Feed one byte. When it completes a reply (end of a line, or a line found
 * too long), the reply is written to reply (cap >= SIM_VMOTOR_REPLY_MAX for
 * it to fit whole; NUL-terminated when room) and its length (with its "\n")
 * returned; 0 otherwise.
 */
size_t sim_vmotor_link_push(sim_vmotor_link_t *l, uint8_t byte, char *reply, size_t cap);

/** sizeof(sim_vmotor_link_t), for bindings. */
size_t sim_vmotor_link_sizeof(void);

/**
 * v with up to 15 significant digits, trailing zeros dropped ("2.5",
 * "-1000000", "1e-07", "nan", "inf"); fixed notation for 1e-5 <= |v| < 1e15.
 * The digits are those of printf's "%.15g" (correctly rounded) for
 * 1e-8 <= |v| < 1e37; beyond, within a unit of the 15th digit.
 * Writes at most cap bytes including a NUL (cap >= 32 always fits); returns
 * the length without the NUL, 0 when it does not fit.
 */
size_t sim_vmotor_format_f64(char *buf, size_t cap, double v);

/**
 * A decimal number (optional sign, digits with an optional point, optional
 * exponent) occupying all of text[0..len): 0 and *v, or -1 when malformed.
 * Correctly rounded for up to 15 significant digits and exponents within
 * +-22 (the common case); otherwise within a few units in the last place.
 */
int sim_vmotor_parse_f64(const char *text, size_t len, double *v);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_SIM_VMOTOR_LINK_H */
