/**
 * @file fw_app.h
 * @brief Drive application: the control core (fw_ctrl) + the CANopen node
 *        (co_node, CiA 402 objects) + the serial telemetry/trace link.
 *
 * One fw_app_t per drive, caller-owned, no malloc, no globals.
 *
 *     fw_app_t app;
 *     fw_app_init(&app, &cfg, 5);
 *     CAN RX interrupt:  fw_app_can_rx(&app, &frame);           // queue only
 *     control interrupt: fw_app_isr(&app, &adc, &out);          // ADC -> step -> duties
 *     supervision (pended by the control interrupt, tail-chained):
 *                        if (fw_app_supervise(&app, &out)) pwm_off();  // monitors, publication
 *     background loop:   fw_app_background(&app);               // CANopen, OD, EMCY, telemetry
 *                        while (fw_app_can_tx_pop(&app, &f)) can_send(&f);
 *                        n = fw_app_uart_read(&app, buf, sizeof buf); uart_write(buf, n);
 *
 * A board does not write that glue itself: fw_board.h is it, once, over
 * fw_port.h (the Cortex-M4F image and the simulated drive both use it).
 *
 * Interrupts and background. fw_app_isr is what the control interrupt does,
 * and nothing else: the core's one ADC conversion and range check
 * (fw_step_adc), the control half of the step (fw_step_into), the period
 * count and the hand-over of the period to the supervision interrupt.
 * fw_app_supervise, the supervision interrupt the board pends after it (lower
 * priority, before the next control interrupt), runs the supervision half
 * (fw_supervise: integrity monitor, protections; a hard fault switches the
 * outputs off at once) and publishes the raw half of the core's snapshot
 * (fw_snapshot_capture) into a lock-free single-producer ring
 * (FW_APP_SNAP_RING entries). A control interrupt that finds the last
 * supervision unfinished raises FW_FAULT_SUPERVISION_MISSED (counted in
 * sup_missed). Neither cost depends on bus traffic. fw_app_background, called by the background loop
 * at its own rate, does the rest: it completes the published snapshots
 * (fw_snapshot_complete, with the configuration their period ran with),
 * converts the period count to the time base, processes the queued CAN frames
 * (NMT, SDO, SYNC, RPDO, heartbeats) and applies what they command, then
 * drains the ring in order - an EMCY per fault change, a telemetry frame
 * every 0x2060:1 periods and a trace sample per period, all from the
 * snapshot of the period they describe - writes the newest snapshot to the
 * OD (statusword, actual values) and produces TPDOs and heartbeat. Where the
 * background changes the core (controlword, mode, references, configuration,
 * a fault raised by a heartbeat or RPDO deadline) it does so inside the
 * lock attached with fw_app_attach_lock (fw_board: the port's critical
 * section), so a control interrupt never sees half an update. When the
 * background falls behind by more than the ring, the oldest unprocessed
 * periods are lost and counted (fw_app_counters_t.snap_overruns): the
 * control interrupt never waits.
 *
 * fw_app_step(app, in, out) is both halves in one call, with inputs already
 * in physical units: the background's input half, the control step, the
 * background's output half. It is for tests and for a controller without an
 * ADC (the null-plant bridge); no board uses it.
 *
 * What the background applies: a written controlword with fw_controlword();
 * modes (0x6060: 9 CSV -> FW_MODE_SPEED, 10 CST -> FW_MODE_FORCE), target
 * velocity (0x60FF, um/s) and target torque (0x6071, per mille of i_max_A).
 * Time is control periods / f_pwm_Hz, counted by the control interrupt (no
 * port timer: the PWM is the drive's clock, in simulation as on the MCU). A
 * lost supervisor heartbeat (0x1016) raises FW_FAULT_HEARTBEAT_LOST through
 * fw_raise_fault(); a missed RPDO deadline (0x1400+n:5) while OPERATION
 * ENABLED raises 0x8250.
 *
 * NMT and the power stage: NMT stop and reset communication switch the
 * power stage off in the same control period (CiA 402 "disable voltage":
 * SWITCH ON DISABLED); reset node restarts the core as after power-up
 * (the configuration of fw_app_init, or the stored one, no fault, SWITCH ON
 * DISABLED).
 *
 * Non-volatile memory (CiA 301 0x1010 / 0x1011): the board glue attaches
 * its port's storage with fw_app_attach_nvm() after fw_app_init(); that is
 * the boot: a stored block whose CRC, product code, firmware version and
 * configuration layout match, and whose configuration passes
 * fw_config_check(), replaces the configuration given to fw_app_init and
 * the storable objects (communication 0x1005..0x1BFF, device tag 0x2042,
 * telemetry 0x2060). Anything wrong: the defaults stay and
 * fw_app_nvm_state() says why. 'save' written to 0x1010:1 stores the
 * running configuration (refused while the power stage is enabled: abort
 * 0x08000022); 'load' written to 0x1011:1 erases the block, so the defaults
 * apply from the next NMT reset node or power-up. NMT reset node loads the
 * block again; reset communication reloads its communication objects.
 * Block: header (magic 'PNVM', format, product code, firmware version,
 * layout hash, length), sizeof(fw_config_t) bytes of configuration, the
 * objects as (index, sub, length, value) records, CRC-32 (IEEE 802.3) of
 * everything before it.
 */
#ifndef PMLSM_FW_APP_H
#define PMLSM_FW_APP_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "pmlsm/co_node.h"
#include "pmlsm/fw_ctrl.h"
#include "pmlsm/fw_port.h"
#include "pmlsm/fw_serial.h"

#ifdef __cplusplus
extern "C" {
#endif

#ifndef FW_APP_TRACE_FLOATS
#define FW_APP_TRACE_FLOATS 4096u /**< trace storage: samples x signals */
#endif
#ifndef FW_APP_UART_LEN
#define FW_APP_UART_LEN 4096u /**< UART TX ring (bytes, power of two) */
#endif
#ifndef FW_APP_SNAP_RING
#define FW_APP_SNAP_RING 8u /**< control periods the background may lag (power of two) */
#endif
#ifndef FW_APP_NVM_LEN
#define FW_APP_NVM_LEN 2048u /**< largest stored parameter block (bytes) */
#endif

/** The port's non-volatile memory as the application uses it (fw_port.h). */
typedef struct {
  fw_port_t *port;
  fw_nvm_status_t (*read)(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len);
  fw_nvm_status_t (*write)(fw_port_t *port, const uint8_t *data, size_t len);
} fw_app_nvm_t;

/** What the last boot (fw_app_attach_nvm, NMT reset node) did with the stored block. */
typedef enum {
  FW_APP_NVM_NONE = 0,        /**< no non-volatile memory (none attached, or unsupported) */
  FW_APP_NVM_EMPTY = 1,       /**< nothing stored: defaults */
  FW_APP_NVM_LOADED = 2,      /**< the stored block is in use */
  FW_APP_NVM_BAD_CRC = 3,     /**< rejected: size, magic or CRC wrong (torn or foreign data) */
  FW_APP_NVM_BAD_PRODUCT = 4, /**< rejected: stored by another product */
  FW_APP_NVM_BAD_VERSION = 5, /**< rejected: other firmware version or configuration layout */
  FW_APP_NVM_BAD_CONTENT = 6, /**< rejected: configuration or an object out of range */
  FW_APP_NVM_READ_ERROR = 7   /**< the medium failed */
} fw_app_nvm_state_t;

/**
 * The lock the background takes around every change of the core (see
 * above); fw_board attaches the port's critical section. Without one
 * (tests, a single-threaded host) the background runs unlocked.
 */
typedef struct {
  fw_port_t *port;
  uint32_t (*enter)(fw_port_t *port);
  void (*exit)(fw_port_t *port, uint32_t key);
} fw_app_lock_t;

/** One control period as the background sees it: the interrupt captures the
 *  snapshot's raw half (fw_snapshot_capture), the background completes it
 *  (fw_snapshot_complete) before it uses it. */
typedef struct {
  fw_snapshot_t snap;
  fw_snapshot_raw_t raw;
  uint32_t step; /**< the application's period index */
  uint32_t slow_gen; /**< fw_snapshot_slow_gen at the last copy of the slow part into snap */
  uint32_t done; /**< step + 1 when snap is completed (background; a slot's new period
                      makes it stale without a store by the interrupt) */
  int32_t ref_count;  /**< the reference sensor's count at the period's sampling */
  uint8_t ref_status; /**< its fw_ref_status_t */
} fw_app_period_t;

/** Application counters (diagnostics, tests). */
typedef struct {
  uint32_t telemetry_sent;
  uint32_t uart_dropped; /**< frames that did not fit the UART ring */
  uint32_t emcy;
  uint32_t hb_lost;
  uint32_t rpdo_timeouts; /**< RPDO event-timer deadlines missed (0x1400+n:5) */
  uint32_t snap_overruns; /**< periods the background never saw (ring full) */
  uint32_t sup_missed; /**< control periods that found the last supervision unfinished
                            (each raises FW_FAULT_SUPERVISION_MISSED) */
} fw_app_counters_t;

/** The control interrupt's hand-over of a period to the supervision interrupt. */
typedef struct {
  fw_app_period_t *p;  /**< the period's ring slot, NULL when the ring was full */
  fw_snapshot_t *dst;  /**< where fw_step_into wrote (p's snapshot, or ctrl.snap) */
  uint32_t head;       /**< the ring's head the slot was taken at */
  uint32_t step;       /**< the period's index */
  unsigned written;    /**< FW_SNAP_W_* groups fw_step_into wrote */
} fw_app_sup_t;

/** The drive application. Treat the members as private. */
typedef struct {
  fw_ctrl_t ctrl;
  /* the control interrupt's data next to the core's: the slots' fields are
     within the immediate offsets of one base register */
  uint32_t step;       /**< control periods since init (written by the interrupt) */
  _Atomic uint32_t ring_head; /**< written by the interrupt only */
  _Atomic uint32_t ring_tail; /**< written by the background only */
  _Atomic uint32_t isr_step;  /**< step as published by the interrupt (the time base) */
  _Atomic uint32_t sup_pending; /**< a period handed over, its supervision not finished */
  _Atomic uint32_t sup_busy;    /**< the supervision is running (fw_app_supervise) */
  fw_app_sup_t sup;    /**< the hand-over (written by the control interrupt only) */
  fw_snapshot_t *last; /**< where the interrupt's last period's snapshot fields are (a
                          slot's, or ctrl.snap when the ring was full; fw_step_into) */
  fw_app_period_t ring[FW_APP_SNAP_RING]; /**< interrupt -> background */
  fw_config_t boot_cfg; /**< configuration of fw_app_init, restored by NMT reset node */
  co_node_t node;
  fw_serial_link_t link;
  fw_trace_t trace;
  float trace_buf[FW_APP_TRACE_FLOATS];
  uint8_t uart[FW_APP_UART_LEN];
  uint32_t uart_head, uart_tail;
  uint32_t f_pwm_Hz;   /**< integer PWM rate for the time base */
  uint32_t now_us;     /**< time base: floor(steps * 1e6 / f_pwm_Hz), modulo 2^32, at time_step */
  uint32_t us_rem;     /**< remainder of that division (< f_pwm_Hz) */
  uint32_t time_step;  /**< the period count now_us was converted at (background) */
  fw_app_lock_t lock;
  int32_t mode_applied; /**< fw_mode_t last accepted by fw_set_mode, -1 none */
  uint8_t cw_pending;
  uint16_t cw;
  uint16_t last_fault;
  uint8_t init_done;
  fw_app_counters_t count;
  fw_app_nvm_t nvm;       /**< attached storage (read == NULL: none) */
  uint8_t nvm_supported;  /**< the port has non-volatile memory (0x1010:1 bit 0) */
  uint8_t nvm_state;      /**< fw_app_nvm_state_t of the last boot */
  uint8_t nvm_buf[FW_APP_NVM_LEN]; /**< block being read or written */
  /* the board (fw_port_info) and its reference sensor (fw_app_ref_sample) */
  const char *board_name; /**< 0x2090:2 */
  uint8_t board_kind;     /**< 0x2090:1, fw_drive_kind_t */
  uint8_t ref_status_in;  /**< the control interrupt's last reading (fw_ref_status_t) ... */
  int32_t ref_count_in;   /**< ... and count, taken into the period's slot */
  uint32_t ref_faults;    /**< 0x2091:6: periods whose reading was not valid */
} fw_app_t;

/**
 * Initialise the core with cfg (see fw_init) and the CANopen node with
 * node_id (1..127; the boot-up message is queued). Returns the fw_init
 * status, FW_ERR_NULL or FW_ERR_RANGE (bad node id).
 */
fw_status_t fw_app_init(fw_app_t *app, const fw_config_t *cfg, uint8_t node_id);

/** What the drive runs on (0x2090:1 fw_drive_kind_t, 0x2090:2 board name: a
 *  static string). fw_board_init sets it from fw_port_info; kept over NMT
 *  resets. Without a call the drive says FW_DRIVE_NO_IO (the OD default). */
void fw_app_set_board(fw_app_t *app, uint8_t kind, const char *board);

/**
 * The reference position sensor's reading of this period (fw_port_ref_read):
 * the control interrupt calls it right before fw_app_isr, so the reading goes
 * with the period's ADC samples into the period's slot. The core never sees
 * it; the background scales it (0x2091:2, :3) into fw_snapshot_t.ref_pos_m
 * (telemetry signal ref_pos_m), 0x2091:4/:5 and TPDO4. Not calling it
 * leaves FW_REF_NONE.
 */
void fw_app_ref_sample(fw_app_t *app, uint8_t status, int32_t count);

/** CAN receive path (ISR side): queue the frame. False when the queue is full. */
bool fw_app_can_rx(fw_app_t *app, const fw_can_frame_t *frame);

/**
 * The control interrupt (app is a fw_app_t *): raw ADC counts in, duties
 * out (the signature of the simulator's step_adc). Its board then pends the
 * supervision interrupt.
 */
void fw_app_isr(void *app, const fw_adc_inputs_t *adc, fw_outputs_t *out);

/**
 * The supervision interrupt (app is a fw_app_t *), once after every control
 * interrupt, before the next one, at a lower priority: the integrity monitor
 * and the protections on the period (fw_supervise), then the period's
 * publication to the background. Returns true when a hard fault switched the
 * outputs off: out then holds duties 0.5 and pwm_enable 0, to be written to
 * the PWM at once. False: out untouched, the control interrupt's duties stand.
 */
bool fw_app_supervise(void *app, fw_outputs_t *out);

/** The background loop's work (app is a fw_app_t *); see above. */
void fw_app_background(void *app);

/** Both halves in one call, physical inputs (tests, null plant; see above). */
void fw_app_step(void *app, const fw_inputs_t *in, fw_outputs_t *out);

/** Attach the lock of the background's core changes (copied; NULL detaches). */
void fw_app_attach_lock(fw_app_t *app, const fw_app_lock_t *lock);

/** Next CAN frame to send; false when none. */
bool fw_app_can_tx_pop(fw_app_t *app, fw_can_frame_t *frame);

/** Pop up to cap bytes of serial output (COBS frames). Returns the count. */
size_t fw_app_uart_read(fw_app_t *app, uint8_t *buf, size_t cap);

/** Core snapshot (app is a const fw_app_t *). */
void fw_app_snapshot(const void *app, fw_snapshot_t *snap);

/** sizeof(fw_app_t), for bindings that allocate it. */
size_t fw_app_sizeof(void);

/** Access for tests and bindings. */
fw_ctrl_t *fw_app_ctrl(fw_app_t *app);
co_node_t *fw_app_node(fw_app_t *app);
const fw_app_counters_t *fw_app_counters(const fw_app_t *app);

/** v rounded to the nearest integer as lrintf (ties to even in the default
 *  rounding mode), saturated to int32; NaN gives 0 (the OD's position, speed
 *  and current objects). */
int32_t fw_app_round_i32(float v);

/** Error register (0x1001) bits for a fault code. */
uint8_t fw_app_error_register(uint16_t fault_code);

/**
 * Attach the port's non-volatile memory and boot from it (see above): call
 * once after fw_app_init, before the first fw_app_step. nvm is copied.
 * Returns what was done with the stored block.
 */
fw_app_nvm_state_t fw_app_attach_nvm(fw_app_t *app, const fw_app_nvm_t *nvm);

/** What the last boot did with the stored block. */
fw_app_nvm_state_t fw_app_nvm_state(const fw_app_t *app);

/**
 * Store the running configuration and the storable objects now (what
 * 'save' in 0x1010:1 does). Returns CO_ABORT_NONE, CO_ABORT_APP (no
 * storage, block too large, medium failed) or CO_ABORT_DEVICE_STATE (power
 * stage enabled).
 */
co_abort_t fw_app_nvm_save(fw_app_t *app);

/** Erase the stored block (what 'load' in 0x1011:1 does); as fw_app_nvm_save. */
co_abort_t fw_app_nvm_erase(fw_app_t *app);

/** CRC-32 (IEEE 802.3 / ISO-HDLC: reflected 0xEDB88320, init and final xor ~0). */
uint32_t fw_app_crc32(const uint8_t *data, size_t len);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_APP_H */
