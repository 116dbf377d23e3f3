/**
 * @file test_board.c
 * @brief The board glue (fw_board.c) over a port written here: a third world
 *        beside the blank port and the simulator's. The port refuses CAN
 *        frames when its mailbox is full and takes UART bytes a few at a
 *        time, counts its critical sections and notes whether the control
 *        interrupt ever ran inside one.
 *
 * Checked: the control interrupt reads the ADC and latches the duties and
 * takes no lock; frames and bytes the port refuses are held and delivered
 * later, in order, never lost or doubled (against a drive on an unlimited
 * port fed the same inputs); the background's changes of the core are
 * made inside balanced critical sections; a background that falls behind
 * loses the oldest periods, counted, while the control interrupt runs on;
 * and an interrupt that arrives in the middle of the background (outside
 * its lock) neither reorders nor drops a published period.
 */
#include <string.h>

#include "pmlsm/fw_app.h"
#include "pmlsm/fw_board.h"
#include "pmlsm/fw_port.h"
#include "tinytest.h"

#define NID 4u
#define CAN_BOX 64u
#define UART_MAX 4096u

struct fw_port {
  fw_adc_inputs_t adc;
  uint32_t adc_reads;
  float duty[3];
  int pwm_on;
  uint32_t pwm_writes;
  fw_can_frame_t can[CAN_BOX];
  uint32_t can_n;
  uint32_t can_room; /* frames it accepts before refusing */
  uint8_t uart[UART_MAX];
  uint32_t uart_n;
  uint32_t uart_per_call; /* 0: unlimited */
  uint32_t depth, enters, unbalanced;
  uint32_t isr_in_lock; /* control interrupts that ran inside a critical section */
  fw_board_t *preempt;  /* run a control interrupt from inside uart_write (once) */
  uint32_t sup_pends;   /* supervision interrupts pended */
  uint8_t sup_pending;
  uint8_t ref_status;   /* the reference sensor this port reports (fw_ref_status_t) */
  int32_t ref_count;
  uint32_t ref_reads;
  uint16_t hw_fault; /* a break the power stage latched (fw_port_hw_fault, once) */
};

void fw_port_info(fw_port_t *p, fw_port_info_t *info) {
  (void)p;
  info->kind = (uint8_t)FW_DRIVE_HARDWARE;
  info->board = "test_board";
}

uint8_t fw_port_ref_read(fw_port_t *p, int32_t *count) {
  p->ref_reads++;
  if (p->ref_status != (uint8_t)FW_REF_NONE) *count = p->ref_count;
  return p->ref_status;
}

void fw_port_pwm_write(fw_port_t *p, const float duty_abc[3], bool enable) {
  memcpy(p->duty, duty_abc, sizeof p->duty);
  p->pwm_on = enable;
  p->pwm_writes++;
}

void fw_port_supervision_pend(fw_port_t *p) {
  p->sup_pends++;
  p->sup_pending = 1u;
}

/* The PWM interrupt and, tail-chained to it, the supervision it pended. */
static void board_isr(fw_board_t *b) {
  fw_board_control_isr(b);
  if (b->port->sup_pending) {
    b->port->sup_pending = 0u;
    fw_board_supervision_isr(b);
  }
}

uint16_t fw_port_hw_fault(fw_port_t *p) {
  const uint16_t f = p->hw_fault;
  p->hw_fault = 0u;
  return f;
}

bool fw_port_adc_read(fw_port_t *p, fw_adc_inputs_t *adc) {
  if (p->depth != 0u) p->isr_in_lock++;
  *adc = p->adc;
  p->adc_reads++;
  return true;
}

bool fw_port_can_send(fw_port_t *p, const fw_can_frame_t *f) {
  if (p->can_room == 0u || p->can_n >= CAN_BOX) return false;
  p->can[p->can_n++] = *f;
  p->can_room--;
  return true;
}

size_t fw_port_uart_write(fw_port_t *p, const uint8_t *data, size_t len) {
  if (p->preempt != NULL) { /* the control interrupt fires in the middle of the background */
    fw_board_t *b = p->preempt;
    p->preempt = NULL;
    board_isr(b);
  }
  size_t n = len;
  if (p->uart_per_call != 0u && n > p->uart_per_call) n = p->uart_per_call;
  if (n > UART_MAX - p->uart_n) n = UART_MAX - p->uart_n;
  memcpy(&p->uart[p->uart_n], data, n);
  p->uart_n += (uint32_t)n;
  return n;
}

uint32_t fw_port_critical_enter(fw_port_t *p) {
  p->enters++;
  return p->depth++;
}

void fw_port_critical_exit(fw_port_t *p, uint32_t key) {
  if (p->depth == 0u || key != p->depth - 1u) p->unbalanced++;
  p->depth = key;
}

fw_nvm_status_t fw_port_nvm_read(fw_port_t *p, uint8_t *buf, size_t cap, size_t *len) {
  (void)p;
  (void)buf;
  (void)cap;
  *len = 0u;
  return FW_NVM_UNSUPPORTED;
}

fw_nvm_status_t fw_port_nvm_write(fw_port_t *p, const uint8_t *data, size_t len) {
  (void)p;
  (void)data;
  (void)len;
  return FW_NVM_UNSUPPORTED;
}

/* two drives: A on the difficult port, B on an unlimited one */
static fw_app_t g_a, g_b;
static fw_board_t g_ba, g_bb;
static struct fw_port g_pa, g_pb;

static void boot(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  memset(&g_pa, 0, sizeof g_pa);
  memset(&g_pb, 0, sizeof g_pb);
  TT_CHECK(fw_app_init(&g_a, &cfg, NID) == FW_OK);
  TT_CHECK(fw_app_init(&g_b, &cfg, NID) == FW_OK);
  TT_CHECK(fw_board_init(&g_ba, &g_a, &g_pa) == FW_APP_NVM_NONE);
  TT_CHECK(fw_board_init(&g_bb, &g_b, &g_pb) == FW_APP_NVM_NONE);
  for (int j = 0; j < 3; j++) {
    g_pa.adc.i_abc_counts[j] = g_pb.adc.i_abc_counts[j] = 2048u;
  }
  g_pa.adc.u_dc_counts = g_pb.adc.u_dc_counts = 2458u; /* ~300 V at the default scaling */
  g_pb.can_room = CAN_BOX;
}

/* boot(), then the boot's current-zero calibration (NOT READY TO SWITCH ON,
 * fw_cal.h) on the ADC samples at mid-scale: the zeros stay 2048 (the tests that
 * enable; the others count the interrupts from the power-up) */
static void boot_ready(void) {
  boot();
  for (int k = 0; k < 4000; k++) {
    if (fw_state(fw_app_ctrl(&g_a)) != FW_CIA402_NOT_READY_TO_SWITCH_ON &&
        fw_state(fw_app_ctrl(&g_b)) != FW_CIA402_NOT_READY_TO_SWITCH_ON) {
      break;
    }
    board_isr(&g_ba);
    board_isr(&g_bb);
    fw_board_background(&g_ba);
    fw_board_background(&g_bb);
  }
  TT_CHECK(fw_state(fw_app_ctrl(&g_a)) == FW_CIA402_SWITCH_ON_DISABLED);
  TT_CHECK(fw_state(fw_app_ctrl(&g_b)) == FW_CIA402_SWITCH_ON_DISABLED);
  TT_CHECK(fw_current_zero_counts(fw_app_ctrl(&g_a), 0u) == 2048.0f);
}

static void rx_both(uint16_t id, const uint8_t d[8]) {
  fw_can_frame_t f;
  memset(&f, 0, sizeof f);
  f.id = id;
  f.dlc = 8u;
  memcpy(f.data, d, 8u);
  TT_CHECK(fw_board_can_rx_isr(&g_ba, &f));
  TT_CHECK(fw_board_can_rx_isr(&g_bb, &f));
}

static void period_both(void) {
  board_isr(&g_ba);
  board_isr(&g_bb);
  fw_board_background(&g_ba);
  fw_board_background(&g_bb);
}

static int frames_equal(const fw_can_frame_t *x, const fw_can_frame_t *y) {
  return x->id == y->id && x->dlc == y->dlc && memcmp(x->data, y->data, x->dlc) == 0;
}

static void test_isr_reads_adc_latches_duties_no_lock(void) {
  boot();
  uint32_t r0 = g_pa.adc_reads;
  for (int k = 0; k < 10; k++) board_isr(&g_ba);
  TT_CHECK(g_pa.adc_reads == r0 + 10u);
  TT_CHECK(g_pa.pwm_writes == 10u);
  TT_CHECK(g_pa.pwm_on == 0); /* SWITCH ON DISABLED: power stage off */
  TT_CHECK(g_pa.enters == 0u); /* the control interrupt takes no lock */
  TT_CHECK(g_ba.adc_failed == 0u);
}

static void test_refused_frames_and_bytes_arrive_later_in_order(void) {
  boot();
  g_pa.can_room = 0u;       /* the controller is full */
  g_pa.uart_per_call = 7u;  /* the UART takes a few bytes per call */
  /* enable over SDO on both drives (controlword 6, 7, 15 in CSV) */
  const uint16_t cws[3] = {0x06, 0x07, 0x0F};
  for (int i = 0; i < 3; i++) {
    uint8_t req[8] = {0x2B, 0x40, 0x60, 0x00, (uint8_t)cws[i], 0, 0, 0};
    rx_both((uint16_t)(0x600 + NID), req);
    for (int k = 0; k < 3; k++) period_both();
  }
  for (int k = 0; k < 600; k++) period_both(); /* 25 ms: telemetry, heartbeat */
  TT_CHECK(g_pa.can_n == 0u && g_ba.tx_is_held == 1u); /* held, not dropped */
  /* the controller frees up one frame per background pass */
  for (int k = 0; k < 4000 && (g_ba.tx_is_held || g_pa.uart_n < g_pb.uart_n); k++) {
    g_pa.can_room = 1u;
    fw_board_background(&g_ba);
  }
  TT_CHECK(g_pa.uart_n == g_pb.uart_n && g_pb.uart_n > 200u);
  TT_CHECK(memcmp(g_pa.uart, g_pb.uart, g_pb.uart_n) == 0);
  /* A's frames are B's, in order; A may lack only B's newest (queue depth) */
  TT_CHECK(g_pa.can_n > 3u);
  uint32_t n = g_pa.can_n < g_pb.can_n ? g_pa.can_n : g_pb.can_n;
  int same = 1;
  for (uint32_t i = 0; i < n; i++) same = same && frames_equal(&g_pa.can[i], &g_pb.can[i]);
  TT_CHECK(same);
  TT_CHECK(g_pa.can[0].id == 0x700 + NID && g_pa.can[0].data[0] == 0u); /* boot-up first */
  /* the same control on both sides */
  TT_CHECK(g_pa.pwm_on == g_pb.pwm_on);
  TT_CHECK(fw_app_counters(&g_a)->snap_overruns == 0u);
}

static void test_background_changes_core_in_balanced_lock(void) {
  boot_ready();
  uint8_t req[8] = {0x2B, 0x40, 0x60, 0x00, 0x06, 0, 0, 0}; /* controlword: shutdown */
  rx_both((uint16_t)(0x600 + NID), req);
  uint32_t e0 = g_pa.enters;
  period_both();
  period_both();
  TT_CHECK(g_pa.enters > e0);
  TT_CHECK(g_pa.unbalanced == 0u && g_pa.depth == 0u);
  TT_CHECK(g_pa.isr_in_lock == 0u);
  TT_CHECK((fw_statusword(fw_app_ctrl(&g_a)) & 0x6Fu) == 0x21u); /* READY TO SWITCH ON */
}

static void test_lagging_background_loses_oldest_counted(void) {
  boot();
  for (uint32_t k = 0; k < FW_APP_SNAP_RING + 9u; k++) board_isr(&g_ba);
  TT_CHECK(fw_app_counters(&g_a)->snap_overruns == 9u);
  TT_CHECK(g_pa.pwm_writes == FW_APP_SNAP_RING + 9u); /* the interrupt never waited */
  fw_board_background(&g_ba);
  board_isr(&g_ba);
  fw_board_background(&g_ba);
  TT_CHECK(fw_app_counters(&g_a)->snap_overruns == 9u); /* room again */
}

static void test_interrupt_inside_background_keeps_order(void) {
  boot();
  g_pb.preempt = NULL;
  /* B: every period in order; A: a control interrupt fires inside A's
     background (while it moves UART bytes) every time */
  uint32_t inside = 0u;
  for (int k = 0; k < 480; k++) {
    board_isr(&g_bb);
    fw_board_background(&g_bb);
    if (g_pa.preempt != NULL) { /* no UART write in the last pass: it fires now */
      g_pa.preempt = NULL;
      board_isr(&g_ba);
    } else if (k > 0) {
      inside++;
    }
    g_pa.preempt = &g_ba; /* one interrupt per period, inside the next UART write */
    g_pa.can_room = CAN_BOX;
    fw_board_background(&g_ba);
  }
  if (g_pa.preempt == NULL) inside++;
  g_pa.preempt = NULL;
  for (int k = 0; k < 8; k++) fw_board_background(&g_ba);
  TT_CHECK(inside >= 15u); /* it did fire inside the background (every telemetry frame) */
  /* the telemetry frames carry the period they describe: A's bytes decode to
     the same stream as B's prefix (same frames, same order) */
  uint32_t n = g_pa.uart_n < g_pb.uart_n ? g_pa.uart_n : g_pb.uart_n;
  TT_CHECK(n > 200u);
  TT_CHECK(memcmp(g_pa.uart, g_pb.uart, n) == 0);
  TT_CHECK(fw_app_counters(&g_a)->snap_overruns == 0u);
  TT_CHECK(g_pa.isr_in_lock == 0u);
}

/* The time base is converted in the background from the period count the
 * interrupt publishes: after every background pass now_us is floor(n * 1e6 /
 * f_pwm) modulo 2^32 of the periods n so far (reference in 64-bit integers),
 * for backgrounds at irregular intervals and across the wrap of the uint32
 * period counter. */
static void test_time_base_counts_periods_exactly(void) {
  boot();
  const uint64_t f = g_a.f_pwm_Hz;
  TT_CHECK(f == 24000u);
  uint64_t n = 0u;
  int good = 1;
  for (int k = 0; k < 300; k++) {
    for (int j = 0; j < 1 + (k * 7) % 8; j++) { /* 1..8 periods: never more than the ring */
      board_isr(&g_ba);
      n++;
    }
    fw_board_background(&g_ba);
    good = good && g_a.now_us == (uint32_t)(n * 1000000u / f);
  }
  TT_CHECK(good);
  /* 50 periods before the period counter wraps (2^32 periods: 49.7 h) */
  n = 0x100000000ull - 50u;
  const uint32_t n32 = (uint32_t)n;
  g_a.step = n32;
  atomic_store(&g_a.isr_step, n32);
  g_a.time_step = n32;
  g_a.now_us = (uint32_t)(n * 1000000u / f);
  g_a.us_rem = (uint32_t)(n * 1000000u % f);
  good = 1;
  for (int k = 0; k < 40; k++) {
    for (int j = 0; j < 1 + k % 5; j++) {
      board_isr(&g_ba);
      n++;
    }
    fw_board_background(&g_ba);
    good = good && g_a.now_us == (uint32_t)(n * 1000000u / f);
  }
  TT_CHECK(good);
  TT_CHECK(n > 0x100000000ull + 50u && g_a.step == (uint32_t)n); /* it did wrap */
}

/* The interrupt publishes the snapshot's raw half; the background completes
 * it later. Periods published before a configuration change are completed
 * with the configuration they were stepped with: the statusword's warning bit
 * (u_dc below u_dc_min_V) of periods stepped before the trip level was raised
 * above the DC link does not show in the OD, the next period's does. */
static void test_pending_periods_keep_their_configuration(void) {
  boot();
  board_isr(&g_ba);
  fw_board_background(&g_ba);
  co_node_t *node = fw_app_node(&g_a);
  TT_CHECK((co_node_get_u32(node, CO_OD_6041_00) & 0x80u) == 0u); /* ~300 V > 150 V */
  for (int k = 0; k < 5; k++) board_isr(&g_ba); /* pending */
  float trip = 400.0f;
  uint32_t bits;
  memcpy(&bits, &trip, sizeof bits);
  uint8_t req[8] = {0x23, 0x50, 0x20, 0x07, (uint8_t)bits, (uint8_t)(bits >> 8),
                    (uint8_t)(bits >> 16), (uint8_t)(bits >> 24)}; /* 0x2050:7 u_dc_min_V */
  fw_can_frame_t f;
  memset(&f, 0, sizeof f);
  f.id = 0x600u + NID;
  f.dlc = 8u;
  memcpy(f.data, req, 8u);
  TT_CHECK(fw_board_can_rx_isr(&g_ba, &f));
  g_pa.can_room = CAN_BOX;
  fw_board_background(&g_ba); /* the write, then the five periods */
  TT_CHECK(fw_get_config(fw_app_ctrl(&g_a))->protection.u_dc_min_V == 400.0f);
  int answered = 0;
  for (uint32_t i = 0; i < g_pa.can_n; i++) {
    answered += g_pa.can[i].id == 0x580u + NID && g_pa.can[i].data[0] == 0x60u; /* accepted */
  }
  TT_CHECK(answered == 1);
  TT_CHECK((co_node_get_u32(node, CO_OD_6041_00) & 0x80u) == 0u);
  board_isr(&g_ba);
  fw_board_background(&g_ba);
  TT_CHECK((co_node_get_u32(node, CO_OD_6041_00) & 0x80u) == 0x80u);
  TT_CHECK((fw_statusword(fw_app_ctrl(&g_a)) & 0x80u) == 0x80u);
}

/* A port whose supervision interrupt never runs (the pend is lost): every
 * control interrupt finds the last period unsupervised, runs the late
 * supervision itself and raises FW_FAULT_SUPERVISION_MISSED, so the drive
 * stays off and the fault still reaches the bus (EMCY 0x6100). */
static void test_lost_supervision_faults_and_is_reported(void) {
  boot();
  for (int k = 0; k < 10; k++) {
    fw_board_control_isr(&g_bb); /* never board_isr: the supervision is lost */
    fw_board_background(&g_bb);
  }
  TT_CHECK(g_pb.sup_pends == 10u);
  TT_CHECK(fw_app_counters(&g_b)->sup_missed == 9u);
  TT_CHECK(fw_fault_code(fw_app_ctrl(&g_b)) == FW_FAULT_SUPERVISION_MISSED);
  TT_CHECK(g_pb.pwm_on == 0);
  int emcy = 0;
  for (uint32_t i = 0; i < g_pb.can_n; i++) {
    const fw_can_frame_t *f = &g_pb.can[i];
    emcy = emcy || (f->id == 0x80u + NID && f->data[0] == 0x00u && f->data[1] == 0x61u);
  }
  TT_CHECK(emcy);
  /* the periods were published: the background saw the fault in a snapshot */
  fw_snapshot_t s;
  fw_app_snapshot(&g_b, &s);
  TT_CHECK(s.fault_code == (uint16_t)FW_FAULT_SUPERVISION_MISSED);
}

/* A supervision preempted by the next control interrupt (sup_busy) is left
 * to finish: that period is not handed over (the hand-over stays the
 * preempted one's), and the fault is raised. */
static void test_preempted_supervision_keeps_its_period(void) {
  boot();
  board_isr(&g_bb);
  fw_board_control_isr(&g_bb); /* period 1 handed over ... */
  const uint32_t step = g_b.sup.step;
  atomic_store(&g_b.sup_busy, 1u); /* ... and its supervision is running */
  fw_board_control_isr(&g_bb);   /* period 2 preempts it */
  TT_CHECK(g_b.sup.step == step && step == 1u);
  TT_CHECK(fw_app_counters(&g_b)->sup_missed == 1u);
  TT_CHECK(fw_fault_code(fw_app_ctrl(&g_b)) == FW_FAULT_SUPERVISION_MISSED);
  atomic_store(&g_b.sup_busy, 0u);
  g_pb.sup_pending = 0u;
  fw_board_supervision_isr(&g_bb); /* the preempted one completes: period 1 published */
  TT_CHECK(atomic_load(&g_b.ring_head) == 2u);
  TT_CHECK(g_b.ring[1].step == 1u);
}


/* The port says what it makes of the drive (0x2090:1, :2); the application
 * keeps it over an NMT reset node, which reloads the OD defaults. */
static void test_port_info_in_od_survives_reset(void) {
  boot();
  co_node_t *node = fw_app_node(&g_a);
  TT_CHECK(co_node_get_u32(node, CO_OD_2090_01) == (uint32_t)FW_DRIVE_HARDWARE);
  char name[32] = {0};
  size_t len = co_od_load(node->od, sizeof node->od, CO_OD_2090_02, (uint8_t *)name,
                          sizeof name - 1u);
  TT_CHECK(len == 10u && memcmp(name, "test_board", 10u) == 0);
  uint8_t nmt[8] = {0x81, NID, 0, 0, 0, 0, 0, 0}; /* NMT reset node */
  fw_can_frame_t f;
  memset(&f, 0, sizeof f);
  f.id = 0x000u;
  f.dlc = 2u;
  memcpy(f.data, nmt, 8u);
  TT_CHECK(fw_board_can_rx_isr(&g_ba, &f));
  g_pa.can_room = CAN_BOX;
  period_both();
  TT_CHECK(co_node_get_u32(node, CO_OD_2090_01) == (uint32_t)FW_DRIVE_HARDWARE);
  memset(name, 0, sizeof name);
  len = co_od_load(node->od, sizeof node->od, CO_OD_2090_02, (uint8_t *)name, sizeof name - 1u);
  TT_CHECK(len == 10u && memcmp(name, "test_board", 10u) == 0);
  /* without a board: the application says "no I/O", never "hardware" */
  fw_app_t bare;
  fw_config_t cfg;
  fw_config_default(&cfg);
  TT_CHECK(fw_app_init(&bare, &cfg, NID) == FW_OK);
  TT_CHECK(co_node_get_u32(fw_app_node(&bare), CO_OD_2090_01) == (uint32_t)FW_DRIVE_NO_IO);
}

/* The reference sensor's reading taken with the period's ADC samples: the
 * period's time (0x2090:3) and count (0x2091:4), scaled (0x2091:5, telemetry
 * ref_pos_m = count x resolution - electrical zero); an invalid reading shows
 * as INT32_MIN / NaN and is counted (0x2091:6). */
static void test_reference_sensor_published_with_its_period(void) {
  boot();
  co_node_t *node = fw_app_node(&g_a);
  g_pa.ref_status = (uint8_t)FW_REF_OK;
  g_pa.ref_count = 123456;
  co_node_set_f32(node, CO_OD_2091_02, 0.5e-6f);
  co_node_set_f32(node, CO_OD_2091_03, 0.01f);
  for (int k = 0; k < 5; k++) board_isr(&g_ba);
  fw_board_background(&g_ba);
  TT_CHECK(g_pa.ref_reads == 5u);
  TT_CHECK(co_node_get_u32(node, CO_OD_2090_03) == 4u); /* the newest period's index */
  TT_CHECK(co_node_get_u32(node, CO_OD_2091_01) == (uint32_t)FW_REF_OK);
  TT_CHECK((int32_t)co_node_get_u32(node, CO_OD_2091_04) == 123456);
  TT_CHECK_NEAR(co_node_get_f32(node, CO_OD_2091_05), 123456 * 0.5e-6 - 0.01, 2e-8);
  fw_snapshot_t snap;
  TT_CHECK_NEAR(g_a.ring[4].snap.ref_pos_m, 123456 * 0.5e-6 - 0.01, 2e-8);
  TT_CHECK(co_node_get_u32(node, CO_OD_2091_06) == 0u);
  /* a fault: no count, no position, counted per period */
  g_pa.ref_status = (uint8_t)FW_REF_FAULT;
  for (int k = 0; k < 3; k++) board_isr(&g_ba);
  fw_board_background(&g_ba);
  TT_CHECK(co_node_get_u32(node, CO_OD_2091_01) == (uint32_t)FW_REF_FAULT);
  TT_CHECK(co_node_get_u32(node, CO_OD_2091_04) == 0x80000000u);
  TT_CHECK(isnan(co_node_get_f32(node, CO_OD_2091_05)));
  TT_CHECK(co_node_get_u32(node, CO_OD_2091_06) == 3u);
  fw_app_snapshot(&g_a, &snap); /* the core's view knows nothing of it */
  (void)snap;
}

/* The control never reads the reference sensor: two drives fed the same ADC
 * samples, one with the true position and one with garbage (and faults),
 * enabled and running in closed loop, give the same duties bit for bit in
 * every period. A leak into the estimator or the control would break it. */
static void test_reference_sensor_never_reaches_the_control(void) {
  boot_ready();
  g_pa.can_room = g_pb.can_room = CAN_BOX;
  const uint16_t cws[3] = {0x06, 0x07, 0x0F};
  for (int i = 0; i < 3; i++) {
    uint8_t req[8] = {0x2B, 0x40, 0x60, 0x00, (uint8_t)cws[i], 0, 0, 0};
    rx_both((uint16_t)(0x600 + NID), req);
    for (int k = 0; k < 3; k++) period_both();
  }
  uint32_t differ = 0u, on = 0u;
  uint32_t x = 12345u;
  for (int k = 0; k < 4800; k++) {
    /* the same ADC samples on both: a 3 kHz ripple and a slow rotation */
    for (int j = 0; j < 3; j++) {
      uint16_t c = (uint16_t)(2048 + (int)(40.0 * sin(0.01 * k + 2.094 * j)) + ((k / 4) % 2 ? 6 : -6));
      g_pa.adc.i_abc_counts[j] = g_pb.adc.i_abc_counts[j] = c;
    }
    g_pa.ref_status = (uint8_t)FW_REF_OK;
    g_pa.ref_count = k * 7;
    x = x * 1664525u + 1013904223u; /* B: garbage, sometimes a fault */
    g_pb.ref_status = (uint8_t)(x >> 30);
    g_pb.ref_count = (int32_t)x;
    period_both();
    differ += memcmp(g_pa.duty, g_pb.duty, sizeof g_pa.duty) != 0 || g_pa.pwm_on != g_pb.pwm_on;
    on += g_pa.pwm_on != 0;
  }
  TT_CHECK(on > 100u); /* the power stage was on: the control ran */
  TT_CHECK(differ == 0u);
  TT_CHECK(fw_fault_code(fw_app_ctrl(&g_a)) == fw_fault_code(fw_app_ctrl(&g_b)));
}

/* The power stage's hardware protection (break input) tripped: the next
 * control interrupt raises FW_FAULT_POWER_STAGE_BREAK in the core before its
 * step, the duties it writes are off, the EMCY names the fault. */
static void test_hardware_break_raises_the_fault(void) {
  boot_ready();
  g_pb.can_room = CAN_BOX;
  const uint16_t cws[3] = {0x06, 0x07, 0x0F};
  for (int i = 0; i < 3; i++) {
    uint8_t req[8] = {0x2B, 0x40, 0x60, 0x00, (uint8_t)cws[i], 0, 0, 0};
    rx_both((uint16_t)(0x600 + NID), req);
    for (int k = 0; k < 3; k++) period_both();
  }
  for (int k = 0; k < 50; k++) period_both();
  TT_CHECK(g_pb.pwm_on != 0);
  g_pb.hw_fault = (uint16_t)FW_FAULT_POWER_STAGE_BREAK;
  board_isr(&g_bb);
  TT_CHECK(g_pb.pwm_on == 0);
  TT_CHECK(fw_fault_code(fw_app_ctrl(&g_b)) == FW_FAULT_POWER_STAGE_BREAK);
  TT_CHECK(g_bb.hw_faults == 1u);
  g_pb.can_n = 0u;
  fw_board_background(&g_bb);
  int emcy = 0;
  for (uint32_t i = 0; i < g_pb.can_n; i++) {
    const fw_can_frame_t *f = &g_pb.can[i];
    emcy = emcy || (f->id == 0x80u + NID && f->data[0] == 0x20u && f->data[1] == 0x23u);
  }
  TT_CHECK(emcy);
}

int main(void) {
  TT_RUN(test_hardware_break_raises_the_fault);
  TT_RUN(test_isr_reads_adc_latches_duties_no_lock);
  TT_RUN(test_port_info_in_od_survives_reset);
  TT_RUN(test_reference_sensor_published_with_its_period);
  TT_RUN(test_reference_sensor_never_reaches_the_control);
  TT_RUN(test_lost_supervision_faults_and_is_reported);
  TT_RUN(test_preempted_supervision_keeps_its_period);
  TT_RUN(test_refused_frames_and_bytes_arrive_later_in_order);
  TT_RUN(test_background_changes_core_in_balanced_lock);
  TT_RUN(test_lagging_background_loses_oldest_counted);
  TT_RUN(test_interrupt_inside_background_keeps_order);
  TT_RUN(test_time_base_counts_periods_exactly);
  TT_RUN(test_pending_periods_keep_their_configuration);
  return TT_SUMMARY();
}
