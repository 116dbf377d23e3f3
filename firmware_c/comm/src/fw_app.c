/**
 * @file fw_app.c
 * @brief Drive application glue: fw_ctrl + CANopen node + serial link: the
 *        life cycle, the control and supervision interrupts' hand-over, the
 *        background loop, the CANopen callbacks (the hooked objects'
 *        dispatch is generated from od.yaml: fw_app_hooks.c) and the
 *        commands they leave to the background. The OD's side of the drive
 *        (sync with the core, the hooked objects' handlers, EMCY) is
 *        fw_app_od.c's, the parameter storage fw_nvm.c's, the trace's
 *        commands and upload fw_trace.c's.
 */
#include "pmlsm/fw_app.h"

#include <math.h>
#include <string.h>

#include "fw_app_hooks.h"
#include "fw_app_internal.h"

/* ---- helpers ------------------------------------------------------------- */

/* Time base: floor(steps * 1e6 / f_pwm) us modulo 2^32, converted in the
 * background from the period count the interrupt publishes (the interrupt
 * only counts): the periods since the last conversion at once, exactly what
 * adding 1e6 / f_pwm per period with the remainder carried gives; continuous
 * when the uint32 period counter wraps (49.7 h at 24 kHz). A change of
 * f_pwm (fw_app_start_core) converts up to the present period first. */
static uint32_t fw_app_time(fw_app_t *app, uint32_t step) {
  uint32_t f = app->f_pwm_Hz > 0u ? app->f_pwm_Hz : 1u;
  uint32_t d = step - app->time_step;
  if (d <= 4000u && app->us_rem <= 294967295u) {
    /* the usual pass (a few periods): the sum fits 32 bits, one hardware
       division instead of the 64-bit library one; the same result */
    uint32_t acc = app->us_rem + d * 1000000u;
    app->now_us += acc / f;
    app->us_rem = acc % f;
  } else {
    uint64_t acc = (uint64_t)app->us_rem + (uint64_t)d * 1000000u;
    app->now_us += (uint32_t)(acc / f); /* modulo 2^32 */
    app->us_rem = (uint32_t)(acc % f);
  }
  app->time_step = step;
  return app->now_us;
}

/* Complete the snapshot of a published period (once). */
static void fw_app_complete(fw_app_t *app, fw_app_period_t *p) {
  if (p->done != p->step + 1u) {
    fw_snapshot_complete(&app->ctrl, &p->snap, &p->raw);
    /* the reference sensor: scaled here, never seen by the core */
    p->snap.ref_pos_m = p->ref_status == (uint8_t)FW_REF_OK
                            ? (float)p->ref_count * CO_NODE_GET_F32(&app->node, 2091_02) -
                                  CO_NODE_GET_F32(&app->node, 2091_03)
                            : NAN;
    p->done = p->step + 1u;
  }
}

/* Complete every published period not processed yet: before the core's
 * configuration changes, so that they are completed with the configuration
 * they were stepped with. */
void fw_app_complete_pending(fw_app_t *app) {
  uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_relaxed);
  uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_acquire);
  for (; tail != head; tail++) {
    fw_app_complete(app, &app->ring[tail % FW_APP_SNAP_RING]);
  }
}

/* The background's changes of the core happen inside this lock (fw_app.h). */
uint32_t fw_app_lock(fw_app_t *app) {
  return app->lock.enter != NULL ? app->lock.enter(app->lock.port) : 0u;
}

void fw_app_unlock(fw_app_t *app, uint32_t key) {
  if (app->lock.exit != NULL) {
    app->lock.exit(app->lock.port, key);
  }
}

void fw_app_attach_lock(fw_app_t *app, const fw_app_lock_t *lock) {
  if (app == NULL) {
    return;
  }
  if (lock == NULL || lock->enter == NULL || lock->exit == NULL) {
    memset(&app->lock, 0, sizeof app->lock);
  } else {
    app->lock = *lock;
  }
}

/* Periods the interrupt published and the background has not processed are
 * dropped when the core restarts (they describe the drive before it). */
static void fw_app_ring_discard(fw_app_t *app) {
  atomic_store_explicit(&app->ring_tail,
                        atomic_load_explicit(&app->ring_head, memory_order_acquire),
                        memory_order_release);
}

fw_status_t fw_app_start_core(fw_app_t *app, const fw_config_t *cfg) {
  fw_app_complete_pending(app);
  (void)fw_app_time(app, app->step); /* the periods so far at the old rate */
  fw_status_t st = fw_init(&app->ctrl, cfg);
  app->last = &app->ctrl.snap; /* fw_init cleared it: the periods so far are gone */
  const fw_config_t *used = fw_get_config(&app->ctrl);
  float f = used != NULL ? used->sensing.f_pwm_Hz : 0.0f;
  app->f_pwm_Hz = (f > 0.0f && f < 4.0e9f) ? (uint32_t)lrintf(f) : 1u;
  app->us_rem %= app->f_pwm_Hz;
  return st;
}

/* ---- CANopen callbacks ----------------------------------------------------- */

static co_abort_t fw_app_on_write(void *ctx, uint16_t index, uint8_t sub, const uint8_t *data,
                                  size_t len) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || data == NULL) {
    return CO_ABORT_GENERAL;
  }
  uint32_t v = co_le_get(data, len > 4u ? 4u : len);
  const fw_app_hook_t *hook = fw_app_hook_find(index, sub);
  /* storage (od.yaml hook_unlocked) is written with the power stage off and
     outside the lock: a flash erase must not hold the control interrupt off */
  if (hook != NULL && !hook->locked) {
    return hook->fn(app, v);
  }
  uint32_t key = fw_app_lock(app);
  co_abort_t r = hook != NULL ? hook->fn(app, v) : fw_app_write_config(app, index, sub, v);
  fw_app_unlock(app, key);
  return r;
}

/** Power stage off at once for NMT stop / reset communication: CiA 402
 *  "disable voltage" (OPERATION ENABLED, QUICK STOP ACTIVE -> SWITCH ON
 *  DISABLED), applied before this period's fw_step. A controlword received
 *  earlier in the same batch is dropped. A running fault reaction keeps its
 *  bounded braking (0x605E: at most fault_brake_time_s for -1, the default; to
 *  standstill within the ramp's bound for 1 and 2). */
static void fw_app_power_off(fw_app_t *app) {
  app->cw_pending = 0u;
  (void)fw_controlword(&app->ctrl, 0x0000u);
}

/** NMT reset node: the application restarts as after power-up: the
 *  configuration given to fw_app_init, replaced by the stored block when
 *  one is attached and valid (fw_app_attach_nvm). */
static void fw_app_reboot(fw_app_t *app) {
  if (!fw_app_nvm_boot(app, false)) { /* the core starts once, on one configuration */
    (void)fw_app_start_core(app, &app->boot_cfg);
  }
  app->cw_pending = 0u;
  app->mode_applied = -1;
  app->last_fault = 0u; /* a restarted node has nothing to reset: no EMCY */
}

static void fw_app_event_locked(fw_app_t *app, co_event_t ev, uint32_t arg);

static void fw_app_on_event(void *ctx, co_event_t ev, uint32_t arg) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL) {
    return;
  }
  uint32_t key = fw_app_lock(app);
  fw_app_event_locked(app, ev, arg);
  fw_app_unlock(app, key);
}

static void fw_app_event_locked(fw_app_t *app, co_event_t ev, uint32_t arg) {
  switch (ev) {
  case CO_EV_HB_LOST:
    app->count.hb_lost++;
    fw_raise_fault(&app->ctrl, FW_FAULT_HEARTBEAT_LOST);
    break;
  case CO_EV_RPDO_TIMEOUT:
    app->count.rpdo_timeouts++;
    if (fw_state(&app->ctrl) == FW_CIA402_OPERATION_ENABLED) {
      fw_raise_fault(&app->ctrl, FW_FAULT_RPDO_TIMEOUT);
    }
    break;
  case CO_EV_NMT:
    if (arg == (uint32_t)CO_NMT_STOPPED) {
      fw_app_power_off(app);
    }
    break;
  case CO_EV_RESET_NODE:
  case CO_EV_RESET_COMM:
    if (ev == CO_EV_RESET_NODE) {
      fw_app_reboot(app);
      fw_app_ring_discard(app);
    } else {
      fw_app_power_off(app);
      /* the stored communication objects are their power-on values */
      (void)fw_app_nvm_boot(app, true);
    }
    /* the OD went back to its defaults: show the core's real state again */
    fw_app_sync_static_od(app);
    co_node_set_u32(&app->node, CO_OD_1001_00, fw_app_error_register(app->last_fault));
    co_node_set_u32(&app->node, CO_OD_6041_00, fw_statusword(&app->ctrl));
    co_node_set_u32(&app->node, CO_OD_603F_00, (uint32_t)fw_fault_code(&app->ctrl));
    break;
  default:
    break;
  }
}

/* ---- UART ring ------------------------------------------------------------------ */

static bool fw_app_uart_push(fw_app_t *app, const uint8_t *data, size_t len) {
  uint32_t used = app->uart_head - app->uart_tail;
  if ((size_t)(FW_APP_UART_LEN - used) < len) {
    app->count.uart_dropped++;
    return false;
  }
  for (size_t i = 0u; i < len; i++) {
    app->uart[(app->uart_head + i) % FW_APP_UART_LEN] = data[i];
  }
  app->uart_head += (uint32_t)len;
  return true;
}

void fw_app_send_frame(fw_app_t *app, uint8_t type, const uint8_t *payload, size_t len) {
  uint8_t frame[FW_SERIAL_MAX_ENCODED];
  size_t n = 0u;
  /* the sequence number advances even if the frame is dropped: the
     receiver sees the gap and counts the loss */
  if (fw_serial_link_send(&app->link, type, payload, len, frame, sizeof frame, &n) ==
      FW_SERIAL_OK) {
    (void)fw_app_uart_push(app, frame, n);
  }
}

size_t fw_app_uart_read(fw_app_t *app, uint8_t *buf, size_t cap) {
  if (app == NULL || buf == NULL) {
    return 0u;
  }
  size_t n = 0u;
  while (n < cap && app->uart_tail != app->uart_head) {
    buf[n++] = app->uart[app->uart_tail % FW_APP_UART_LEN];
    app->uart_tail++;
  }
  return n;
}

/* ---- life cycle --------------------------------------------------------------- */

fw_status_t fw_app_init(fw_app_t *app, const fw_config_t *cfg, uint8_t node_id) {
  if (app == NULL || cfg == NULL) {
    return FW_ERR_NULL;
  }
  if (node_id < 1u || node_id > 127u) {
    return FW_ERR_RANGE;
  }
  memset(app, 0, sizeof *app);
  app->mode_applied = -1;
  app->board_kind = (uint8_t)FW_DRIVE_NO_IO; /* until the board says (fw_app_set_board) */
  app->boot_cfg = *cfg;
  fw_status_t st = fw_app_start_core(app, cfg);
  co_callbacks_t cb = {app, fw_app_on_write, fw_app_on_event};
  (void)co_node_init(&app->node, node_id, &cb);
  fw_serial_link_init(&app->link);
  (void)fw_trace_init(&app->trace, app->trace_buf, FW_APP_TRACE_FLOATS);
  fw_app_sync_static_od(app);
  co_node_set_u32(&app->node, CO_OD_6041_00, fw_statusword(&app->ctrl));
  app->init_done = 1u;
  return st;
}

void fw_app_set_board(fw_app_t *app, uint8_t kind, const char *board) {
  if (app == NULL) {
    return;
  }
  app->board_kind = kind;
  app->board_name = board;
  co_node_set_u32(&app->node, CO_OD_2090_01, kind);
  co_node_set_str(&app->node, CO_OD_2090_02, board != NULL ? board : "");
}

FW_ISR_OPT void fw_app_ref_sample(fw_app_t *app, uint8_t status, int32_t count) {
  app->ref_status_in = status;
  app->ref_count_in = count;
}

bool fw_app_can_rx(fw_app_t *app, const fw_can_frame_t *frame) {
  if (app == NULL || frame == NULL) {
    return false;
  }
  return co_node_rx_isr(&app->node, frame) == CO_OK;
}

bool fw_app_can_tx_pop(fw_app_t *app, fw_can_frame_t *frame) {
  if (app == NULL || frame == NULL) {
    return false;
  }
  return co_node_tx_pop(&app->node, frame);
}

void fw_app_snapshot(const void *app, fw_snapshot_t *snap) {
  const fw_app_t *a = (const fw_app_t *)app;
  if (a == NULL || snap == NULL) {
    return;
  }
  fw_get_snapshot_of(&a->ctrl, a->last, snap);
}

size_t fw_app_sizeof(void) { return sizeof(fw_app_t); }

fw_ctrl_t *fw_app_ctrl(fw_app_t *app) { return app != NULL ? &app->ctrl : NULL; }
co_node_t *fw_app_node(fw_app_t *app) { return app != NULL ? &app->node : NULL; }
const fw_app_counters_t *fw_app_counters(const fw_app_t *app) {
  return app != NULL ? &app->count : NULL;
}

/* ---- step ---------------------------------------------------------------------- */

static void fw_app_apply_commands(fw_app_t *app) {
  co_node_t *n = &app->node;
  const fw_config_t *cfg = fw_get_config(&app->ctrl);
  uint32_t key = fw_app_lock(app);
  if (app->cw_pending) {
    app->cw_pending = 0u;
    (void)fw_controlword(&app->ctrl, app->cw);
  }
  int32_t mode = CO_NODE_GET_I(n, 6060_00);
  fw_mode_t m = mode == FW_APP_MODE_CST ? FW_MODE_FORCE : FW_MODE_SPEED;
  if (app->mode_applied != (int32_t)m && fw_set_mode(&app->ctrl, m) == FW_OK) {
    app->mode_applied = (int32_t)m;
  }
  if (cfg != NULL) {
    float v_mps = (float)CO_NODE_GET_I(n, 60FF_00) * 1.0e-6f;
    (void)fw_set_speed_ref(&app->ctrl, fw_units_mps_to_radps_e(cfg, v_mps));
    float t_pm = (float)CO_NODE_GET_I(n, 6071_00);
    (void)fw_set_iq_ref(&app->ctrl, t_pm * 1.0e-3f * cfg->loops.i_max_A);
  }
  /* a fault reset does not clear a heartbeat that is still missing, nor an
     RPDO deadline that is still missed (once enabled again) */
  if (fw_fault_code(&app->ctrl) == FW_FAULT_NONE) {
    for (uint32_t k = 0u; k < CO_HB_CONSUMERS; k++) {
      if (app->node.hb[k].lost) {
        fw_raise_fault(&app->ctrl, FW_FAULT_HEARTBEAT_LOST);
        break;
      }
    }
  }
  if (fw_fault_code(&app->ctrl) == FW_FAULT_NONE &&
      fw_state(&app->ctrl) == FW_CIA402_OPERATION_ENABLED) {
    for (uint32_t k = 0u; k < CO_OD_NR_RPDO; k++) {
      if (app->node.rpdo[k].timed_out) {
        fw_raise_fault(&app->ctrl, FW_FAULT_RPDO_TIMEOUT);
        break;
      }
    }
  }
  fw_app_unlock(app, key);
}

static void fw_app_serial(fw_app_t *app, const fw_snapshot_t *s, uint32_t step) {
  co_node_t *n = &app->node;
  /* the telemetry configuration (0x2060) read in place: as cheap as a cached
     copy, and an SDO write is seen at the next period without a hook */
  uint32_t dec = CO_NODE_GET(n, 2060_01);
  if (dec > 0u && step % dec == 0u) {
    uint8_t cnt = (uint8_t)CO_NODE_GET(n, 2060_02);
    uint8_t payload[FW_SERIAL_MAX_PAYLOAD];
    if (cnt > FW_SERIAL_MAX_SIGNALS) {
      cnt = FW_SERIAL_MAX_SIGNALS;
    }
    size_t len = fw_serial_telemetry_payload(s, &n->od[CO_OD_OFF_2060_03], cnt, payload,
                                             sizeof payload);
    if (len > 0u) {
      fw_app_send_frame(app, FW_SERIAL_TYPE_TELEMETRY, payload, len);
      app->count.telemetry_sent++;
    }
  }
  fw_app_trace_period(app, s);
}

/* ---- the control and supervision interrupts ---------------------------------- */

/* Before the step: the slot of this period (NULL when the ring is full: the
 * background is behind), into whose snapshot the core writes the period's
 * fields (fw_step_into); the acquire orders the background's last reads of
 * that slot before these writes. */
FW_ISR_OPT static inline fw_app_period_t *fw_app_slot(fw_app_t *app, uint32_t head) {
  uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_acquire);
  return FW_LIKELY(head - tail < FW_APP_SNAP_RING) ? &app->ring[head % FW_APP_SNAP_RING] : NULL;
}

/* After the supervision: complete the period's raw half in its slot p (the
 * blocks' states; the background completes the rest) and publish it to the
 * background. dst is where the step wrote (p's snapshot, or ctrl.snap when
 * the ring is full); the groups it did not write are the period before's.
 * One release fence for the slot and the head. */
FW_ISR_OPT static void fw_app_publish(fw_app_t *app, const fw_app_sup_t *sp) {
  fw_app_period_t *p = sp->p;
  fw_snapshot_t *dst = sp->dst;
  if (FW_UNLIKELY(sp->written != FW_SNAP_W_ALL)) {
    fw_snapshot_carry(dst, app->last, sp->written);
  }
  app->last = dst;
  if (FW_LIKELY(p != NULL)) {
    fw_snapshot_capture_state(&app->ctrl, &p->snap, &p->raw);
    /* the fields that change only at start-up events and on commands: when
       they changed since this slot last had them (the slot keeps its copy) */
    const uint32_t gen = fw_snapshot_slow_gen(&app->ctrl);
    if (FW_UNLIKELY(p->slow_gen != gen)) {
      fw_snapshot_capture_slow(&app->ctrl, &p->snap);
      p->slow_gen = gen;
    }
    p->step = sp->step; /* p->done is then not step + 1: not completed */
  } else {
    app->count.snap_overruns++; /* the background is behind: it never sees this period */
  }
  atomic_thread_fence(memory_order_release);
  atomic_store_explicit(&app->ring_head, FW_LIKELY(p != NULL) ? sp->head + 1u : sp->head,
                        memory_order_relaxed);
}

/* The supervision half: the core's supervision of the period the control
 * half handed over, then its publication. */
FW_ISR_OPT static FW_ALWAYS_INLINE bool fw_app_sup(fw_app_t *app, fw_outputs_t *out) {
  if (FW_UNLIKELY(atomic_load_explicit(&app->sup_pending, memory_order_acquire) == 0u)) {
    return false; /* nothing handed over */
  }
  atomic_store_explicit(&app->sup_busy, 1u, memory_order_relaxed);
  const bool off = fw_supervise(&app->ctrl, out, app->sup.dst);
  fw_app_publish(app, &app->sup);
  atomic_store_explicit(&app->sup_pending, 0u, memory_order_release);
  atomic_store_explicit(&app->sup_busy, 0u, memory_order_relaxed);
  return off;
}

/* The control interrupt found the last period's supervision not finished: the
 * timing is broken (the supervision interrupt starved, or a port that never
 * pends it), a hard fault (FW_FAULT_SUPERVISION_MISSED), and counted. Not
 * started: the late supervision runs here, so the period is judged and
 * published (a broken port still shows its fault on the bus). Started and
 * preempted by this interrupt: it is left to finish; the caller does not
 * hand this period over (true). */
static FW_NOINLINE bool fw_app_late(fw_app_t *app) {
  app->count.sup_missed++;
  const bool preempted = atomic_load_explicit(&app->sup_busy, memory_order_relaxed) != 0u;
  if (!preempted) {
    fw_outputs_t off;
    (void)fw_app_sup(app, &off); /* the duties of that period are long applied */
  }
  fw_raise_fault(&app->ctrl, FW_FAULT_SUPERVISION_MISSED);
  return preempted;
}

/* The control half of one period (the control interrupt's, or fw_app_step's):
 * the core steps into this period's slot (ctrl.snap when the ring is full)
 * from the ADC counts or, adc NULL, the physical inputs; the period is
 * counted (the time base) and handed to the supervision (fw_app_late when the
 * last one has not finished). */
FW_ISR_OPT static FW_ALWAYS_INLINE void fw_app_control(fw_app_t *app, const fw_inputs_t *in,
                                                       const fw_adc_inputs_t *adc,
                                                       fw_outputs_t *out) {
  const uint32_t step = app->step;
  bool preempted = false;
  if (FW_UNLIKELY(atomic_load_explicit(&app->sup_pending, memory_order_relaxed) != 0u)) {
    preempted = fw_app_late(app);
  }
  const uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_relaxed);
  fw_app_period_t *p = FW_LIKELY(!preempted) ? fw_app_slot(app, head) : NULL;
  fw_snapshot_t *dst = FW_LIKELY(p != NULL) ? &p->snap : &app->ctrl.snap;
  const unsigned written = fw_step_into(&app->ctrl, in, adc, out, dst);
  if (FW_LIKELY(p != NULL)) { /* the reference sensor's reading of this period, as sampled */
    p->ref_count = app->ref_count_in;
    p->ref_status = app->ref_status_in;
  }
  if (FW_LIKELY(!preempted)) {
    fw_app_sup_t *sp = &app->sup;
    sp->p = p;
    sp->dst = dst;
    sp->written = written;
    sp->head = head;
    sp->step = step;
    atomic_store_explicit(&app->sup_pending, 1u, memory_order_release);
  }
  app->step = step + 1u;
  atomic_store_explicit(&app->isr_step, step + 1u, memory_order_release);
}

FW_ISR_OPT void fw_app_isr(void *ctx, const fw_adc_inputs_t *adc, fw_outputs_t *out) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || adc == NULL || out == NULL) {
    if (out != NULL) {
      memset(out, 0, sizeof *out);
    }
    return;
  }
  fw_app_control(app, NULL, adc, out); /* the core's one ADC conversion and range check */
}

FW_ISR_OPT bool fw_app_supervise(void *ctx, fw_outputs_t *out) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || out == NULL) {
    return false;
  }
  return fw_app_sup(app, out);
}

/* ---- the background loop ------------------------------------------------------- */

/* Input half: frames in, commands to the core. */
static void fw_app_bg_input(fw_app_t *app, uint32_t now) {
  co_node_process_rx(&app->node, now);
  fw_app_apply_commands(app);
}

/* Output half: every published period in order, the OD, frames out. The
 * newest period's slot is released only after the OD was written from it. */
static void fw_app_bg_output(fw_app_t *app, uint32_t now) {
  uint32_t tail = atomic_load_explicit(&app->ring_tail, memory_order_relaxed);
  uint32_t head = atomic_load_explicit(&app->ring_head, memory_order_acquire);
  while (tail != head) {
    fw_app_period_t *p = &app->ring[tail % FW_APP_SNAP_RING];
    fw_app_complete(app, p);
    if (p->ref_status == (uint8_t)FW_REF_FAULT || p->ref_status == (uint8_t)FW_REF_NOT_REFERENCED) {
      app->ref_faults++;
    }
    fw_app_emcy(app, &p->snap);
    fw_app_serial(app, &p->snap, p->step);
    if (tail + 1u == head) {
      fw_app_update_od(app, p);
    }
    tail++;
    atomic_store_explicit(&app->ring_tail, tail, memory_order_release);
  }
  co_node_process_tx(&app->node, now);
}

void fw_app_background(void *ctx) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL) {
    return;
  }
  uint32_t now = fw_app_time(app, atomic_load_explicit(&app->isr_step, memory_order_acquire));
  fw_app_bg_input(app, now);
  fw_app_bg_output(app, now);
}

void fw_app_step(void *ctx, const fw_inputs_t *in, fw_outputs_t *out) {
  fw_app_t *app = (fw_app_t *)ctx;
  if (app == NULL || in == NULL || out == NULL) {
    if (out != NULL) {
      memset(out, 0, sizeof *out);
    }
    return;
  }
  uint32_t now = fw_app_time(app, app->step);
  fw_app_bg_input(app, now);
  fw_app_control(app, in, NULL, out);
  (void)fw_app_sup(app, out);
  fw_app_bg_output(app, now);
}
