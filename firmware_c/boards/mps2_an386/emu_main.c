/**
 * @file emu_main.c
 * @brief The emulated board: the whole drive (fw_app: control core, CANopen
 *        slave, serial telemetry, through the board glue fw_board_*) on
 *        QEMU's mps2-an386 (Cortex-M4F), with the simulator's plant compiled
 *        in as its virtual motor. The bench reaches it as a real drive:
 *        CAN through a serial-line CAN adapter (slcan) on UART0, telemetry
 *        on UART1; UART2 is the rig's load machine (sim_vmotor_link.h).
 *
 *   TIMER0 (the PWM timer; it plays the hardware): the ADC conversion and
 *       the scale's reading at t_k (sim_sample, sim_ref_sample), the plant
 *       over [t_k, t_k + T) with the duties the previous control interrupt
 *       latched (sim_plant_step): sim_run's order, period for period. Then
 *       it pends the control interrupt.
 *   control interrupt (IRQ 31, no device on it): fw_board_control_isr; its
 *       fw_port_adc_read / fw_port_ref_read return this period's readings,
 *       fw_port_pwm_write latches the duties for the next TIMER0.
 *   PendSV: fw_board_supervision_isr.
 *   UART0 / UART2 receive: one byte into a ring (QEMU's UART holds one).
 *   background (thread mode): fw_board_background, then the bytes: slcan
 *       lines to fw_board_can_rx_isr and replies, the load machine's lines,
 *       the rings to the UARTs; then WFI.
 *
 * The drive's time is its period count. The timer runs EMU_DILATION times
 * slower than 1/f_pwm in QEMU's virtual time (-icount shift=0: 1 ns per
 * instruction), idle time skipped (sleep=off): the plant still advances
 * 1/f_pwm per period. Every part's cost is measured on TIMER1 (SYSCLK ticks,
 * 40 instructions each), exclusive of the interrupts that preempted it, and
 * reported by the load machine's "stats".
 */
#include <string.h>

#include "emu_board.h"
#include "emu_boot.h"
#include "emu_hw.h"
#include "emu_semihost.h"
#include "pmlsm/fw_app.h"
#include "pmlsm/fw_board.h"
#include "pmlsm/fw_version.h"
#include "sim_vmotor_link.h"

/* cm4_startup.c */
void cm4_reset_handler(void);
void cm4_default_handler(void);
void cm4_fault_handler(void);
extern uint32_t __stack_top;

#define EMU_SIM_BYTES (128u * 1024u) /**< storage for the virtual motor (sim_sizeof) */
#define EMU_RX_FRAMES_PER_PASS 32u

/* the board's instances (the core has no globals; a board has its hardware) */
static fw_app_t g_app;
static fw_board_t g_board;
static struct fw_port g_port;
static sim_vmotor_link_t g_link;
static byte_ring_t g_load_rx, g_load_tx;
static uint8_t g_load_rx_buf[EMU_LOAD_RX_LEN], g_load_tx_buf[EMU_LOAD_TX_LEN];
static _Alignas(8) uint8_t g_sim_mem[EMU_SIM_BYTES];

/* ---- cost measurements ---------------------------------------------------------- */

typedef struct {
  uint32_t t0, inner0;
} emu_mark_t;

static inline uint32_t now_ticks(void) {
  return emu_rd(EMU_TIMER1_BASE, EMU_TIMER_VALUE);
}

static inline emu_mark_t prof_begin(void) {
  const uint32_t pm = cm4_primask_save(); /* the two readings at one instant */
  const emu_mark_t m = {now_ticks(), g_port.prof.inner};
  cm4_primask_restore(pm);
  return m;
}

/** Ticks since m, less those of the handlers that preempted this one. */
static inline uint32_t prof_end(emu_mark_t m) {
  const uint32_t pm = cm4_primask_save();
  const uint32_t elapsed = m.t0 - now_ticks(); /* a down-counter */
  const uint32_t excl = elapsed - (g_port.prof.inner - m.inner0);
  g_port.prof.inner += excl;
  cm4_primask_restore(pm);
  return excl;
}

static void cost_add(emu_cost_t *c, uint32_t ticks, uint32_t at) {
  c->n++;
  c->sum += ticks;
  c->last = ticks;
  if (ticks > c->max) {
    c->max = ticks;
    c->max_at = at;
  }
}

/* ---- interrupt handlers --------------------------------------------------------- */

void emu_timer0_irq(void);
void emu_control_irq(void);
void emu_pendsv_handler(void);
void emu_uart0_rx_irq(void);
void emu_uart2_rx_irq(void);

/** The PWM period: what sim_run does per period, as the hardware would. */
void emu_timer0_irq(void) {
  const emu_mark_t m = prof_begin();
  struct fw_port *p = &g_port;
  emu_wr(EMU_TIMER0_BASE, EMU_TIMER_INTCLEAR, 1u);
  if (p->period_busy) {
    p->overruns++; /* the last period's control or supervision has not finished */
  }
  sim_sample(p->sim, NULL, &p->adc); /* the ADC at t_k */
  p->adc_fresh = 1u;
  p->ref_status = sim_ref_sample(p->sim, &p->ref_count); /* the scale, same instant */
  const float duty[3] = {p->duty[0], p->duty[1], p->duty[2]};
  sim_plant_step(p->sim, duty, p->pwm_on); /* [t_k, t_k + T) on the latched duties */
  p->periods++;
  p->period_busy = 1u;
  cm4_irq_pend(EMU_IRQ_CONTROL);
  const uint32_t t = prof_end(m);
  cost_add(&p->prof.plant, t, p->periods);
  p->prof.period_acc = t;
}

void emu_control_irq(void) {
  const emu_mark_t m = prof_begin();
  fw_board_control_isr(&g_board);
  const uint32_t t = prof_end(m);
  cost_add(&g_port.prof.control, t, g_port.periods);
  g_port.prof.period_acc += t;
}

void emu_pendsv_handler(void) {
  const emu_mark_t m = prof_begin();
  fw_board_supervision_isr(&g_board);
  const uint32_t t = prof_end(m);
  emu_prof_t *pr = &g_port.prof;
  cost_add(&pr->supervision, t, g_port.periods);
  cost_add(&pr->period, pr->period_acc + t, g_port.periods);
  g_port.period_busy = 0u;
}

/** One received byte into its ring (QEMU's CMSDK UART has no FIFO). */
static uint32_t uart_rx(uint32_t base, byte_ring_t *ring) {
  uint32_t n = 0u;
  emu_wr(base, EMU_UART_INTSTATUS, EMU_UART_INT_RX);
  while (emu_rd(base, EMU_UART_STATE) & EMU_UART_STATE_RXFULL) {
    (void)byte_ring_put(ring, (uint8_t)emu_rd(base, EMU_UART_DATA));
    n++;
  }
  if (emu_rd(base, EMU_UART_STATE) & EMU_UART_STATE_RXOVR) {
    emu_wr(base, EMU_UART_STATE, EMU_UART_STATE_RXOVR);
  }
  return n;
}

void emu_uart0_rx_irq(void) {
  const emu_mark_t m = prof_begin();
  g_port.can_rx_bytes += uart_rx(EMU_UART0_BASE, &g_port.can_rx);
  cost_add(&g_port.prof.rx, prof_end(m), g_port.periods);
}

void emu_uart2_rx_irq(void) {
  const emu_mark_t m = prof_begin();
  g_port.load_rx_bytes += uart_rx(EMU_UART2_BASE, &g_load_rx);
  cost_add(&g_port.prof.rx, prof_end(m), g_port.periods);
}

/* ---- vector table ------------------------------------------------------------------ */

typedef void (*emu_handler_t)(void);
typedef struct {
  const uint32_t *stack_top;
  emu_handler_t handler[15u + EMU_IRQ_COUNT];
} emu_vectors_t;

#define D_ cm4_default_handler
__attribute__((section(".vectors"), used)) static const emu_vectors_t emu_vectors = {
    &__stack_top,
    {
        cm4_reset_handler, cm4_fault_handler /* NMI */, cm4_fault_handler /* HardFault */,
        cm4_fault_handler /* MemManage */, cm4_fault_handler /* BusFault */,
        cm4_fault_handler /* UsageFault */, NULL, NULL, NULL, NULL, D_ /* SVCall */,
        D_ /* DebugMon */, NULL, emu_pendsv_handler, D_ /* SysTick */,
        /* IRQ 0..31 */
        emu_uart0_rx_irq, D_, D_, D_, emu_uart2_rx_irq, D_, D_, D_, /* 0..7 */
        emu_timer0_irq, D_, D_, D_, D_, D_, D_, D_,                 /* 8..15 */
        D_, D_, D_, D_, D_, D_, D_, D_,                             /* 16..23 */
        D_, D_, D_, D_, D_, D_, D_, emu_control_irq,                /* 24..31 */
    }};
#undef D_

/* ---- fatal path ------------------------------------------------------------------- */

void board_fatal(uint32_t code) {
  emu_line_t l = {.n = 0u};
  emu_line_str(&l, "mps2_an386: fatal ");
  emu_line_hex(&l, code, 4u);
  emu_line_str(&l, code == 0xFA17u
                       ? " (fault)"
                       : (code == 0xBADu ? " (unexpected interrupt)" : " (main returned)"));
  emu_line_str(&l, ", ICSR ");
  emu_line_hex(&l, CM4_REG(CM4_SCB_ICSR), 8u);
  emu_line_str(&l, ", CFSR ");
  emu_line_hex(&l, CM4_REG(0xE000ED28u), 8u);
  emu_line_str(&l, ", HFSR ");
  emu_line_hex(&l, CM4_REG(0xE000ED2Cu), 8u);
  emu_line_str(&l, ", BFAR ");
  emu_line_hex(&l, CM4_REG(0xE000ED38u), 8u);
  emu_line_emit(&l);
  emu_sh_exit(3u);
}

/* ---- the load machine ------------------------------------------------------------ */

static uint32_t plant_lock_enter(void *ctx) {
  (void)ctx;
  return cm4_primask_save(); /* the plant is TIMER0's, the most urgent interrupt */
}

static void plant_lock_exit(void *ctx, uint32_t key) {
  (void)ctx;
  cm4_primask_restore(key);
}

typedef struct {
  char *buf;
  size_t cap, n;
} emu_text_t;

static void text_str(emu_text_t *t, const char *s) {
  while (*s != '\0' && t->n < t->cap) {
    t->buf[t->n++] = *s++;
  }
}

static void text_u64(emu_text_t *t, uint64_t v) {
  char d[20], s[21];
  size_t n = 0u;
  do {
    d[n++] = (char)('0' + (int)(v % 10u));
    v /= 10u;
  } while (v != 0u);
  for (size_t k = 0u; k < n; k++) {
    s[k] = d[n - 1u - k];
  }
  s[n] = '\0';
  text_str(t, s);
}

/** " name=mean/max@period" in instructions. */
static void text_cost(emu_text_t *t, const char *name, const emu_cost_t *c) {
  text_str(t, " ");
  text_str(t, name);
  text_str(t, "=");
  text_u64(t, c->n > 0u ? c->sum * EMU_INSN_PER_TICK / c->n : 0u);
  text_str(t, "/");
  text_u64(t, (uint64_t)c->max * EMU_INSN_PER_TICK);
  text_str(t, "@");
  text_u64(t, c->max_at);
}

/** The load machine's "stats": the board's cost figures (instructions: mean/max@period). */
static size_t board_stats(void *ctx, char *buf, size_t cap) {
  (void)ctx;
  emu_text_t t = {buf, cap, 0u};
  emu_prof_t pr;
  const uint32_t key = plant_lock_enter(NULL);
  pr = g_port.prof; /* one consistent copy */
  const uint32_t periods = g_port.periods, overruns = g_port.overruns;
  plant_lock_exit(NULL, key);
  text_str(&t, "dilation=");
  text_u64(&t, EMU_DILATION);
  text_str(&t, " timer_insn=");
  text_u64(&t, (uint64_t)emu_rd(EMU_TIMER0_BASE, EMU_TIMER_RELOAD) * EMU_INSN_PER_TICK +
                   EMU_INSN_PER_TICK);
  text_str(&t, " periods=");
  text_u64(&t, periods);
  text_str(&t, " overruns=");
  text_u64(&t, overruns);
  text_cost(&t, "plant", &pr.plant);
  text_cost(&t, "control", &pr.control);
  text_cost(&t, "supervision", &pr.supervision);
  text_cost(&t, "period", &pr.period);
  text_cost(&t, "background", &pr.background);
  text_str(&t, " background_per_period=");
  text_u64(&t, periods > 0u ? pr.background.sum * EMU_INSN_PER_TICK / periods : 0u);
  text_cost(&t, "rx", &pr.rx);
  text_str(&t, " can_rx=");
  text_u64(&t, g_port.can_rx_bytes);
  text_str(&t, " can_tx=");
  text_u64(&t, g_port.can_tx_bytes);
  text_str(&t, " can_frames_out=");
  text_u64(&t, g_port.slcan.count.frames_out);
  text_str(&t, " can_frames_in=");
  text_u64(&t, g_port.slcan.count.frames_in);
  text_str(&t, " tel_tx=");
  text_u64(&t, g_port.tel_tx_bytes);
  text_str(&t, " rx_lost=");
  text_u64(&t, (uint64_t)g_port.can_rx.dropped + g_load_rx.dropped);
  text_str(&t, " sup_missed=");
  text_u64(&t, fw_app_counters(&g_app)->sup_missed);
  text_str(&t, " snap_overruns=");
  text_u64(&t, fw_app_counters(&g_app)->snap_overruns);
  return t.n;
}

/* ---- background ------------------------------------------------------------------ */

static size_t ring_room(byte_ring_t *r) {
  return (size_t)(r->mask + 1u - byte_ring_used(r));
}

/** slcan lines from the host: replies to the host, frames to the drive. */
static void can_rx_move(void) {
  struct fw_port *p = &g_port;
  if (p->rx_frame_held) {
    if (!fw_board_can_rx_isr(&g_board, &p->rx_frame)) {
      return; /* the drive's queue is still full: the bytes wait in the ring */
    }
    p->rx_frame_held = 0u;
  }
  uint32_t frames = 0u;
  uint32_t lost = p->can_rx.dropped;
  uint8_t b;
  while (frames < EMU_RX_FRAMES_PER_PASS && byte_ring_get(&p->can_rx, &b)) {
    fw_can_frame_t f;
    slcan_reply_t r;
    const slcan_event_t ev = slcan_push(&p->slcan, b, &f, &r);
    if (r.len > 0u) {
      if (ring_room(&p->can_tx) >= r.len) {
        (void)byte_ring_write(&p->can_tx, (const uint8_t *)r.text, r.len);
      } else {
        p->replies_dropped++;
      }
    }
    if (ev == SLCAN_FRAME) {
      frames++;
      if (!fw_board_can_rx_isr(&g_board, &f)) {
        p->rx_frame = f; /* offered again next pass, before any later byte */
        p->rx_frame_held = 1u;
        p->can_rx_held++;
        slcan_flag(&p->slcan, SLCAN_F_RX_FULL);
        break;
      }
    }
  }
  if (lost != 0u) {
    slcan_flag(&p->slcan, SLCAN_F_OVERRUN);
  }
}

/** The load machine's lines. */
static void load_rx_move(void) {
  char reply[SIM_VMOTOR_REPLY_MAX];
  uint8_t b;
  while (byte_ring_get(&g_load_rx, &b)) {
    const size_t n = sim_vmotor_link_push(&g_link, b, reply, sizeof reply);
    if (n > 0u) {
      if (ring_room(&g_load_tx) >= n) {
        (void)byte_ring_write(&g_load_tx, (const uint8_t *)reply, n);
      } else {
        g_port.replies_dropped++;
      }
    }
  }
}

/** Ring to UART while the UART takes bytes (QEMU sends each at once). */
static uint32_t uart_tx(uint32_t base, byte_ring_t *ring) {
  uint32_t n = 0u;
  uint8_t b;
  while (!(emu_rd(base, EMU_UART_STATE) & EMU_UART_STATE_TXFULL) && byte_ring_get(ring, &b)) {
    emu_wr(base, EMU_UART_DATA, b);
    n++;
  }
  return n;
}

static bool tx_ready(uint32_t base, byte_ring_t *ring) {
  return byte_ring_used(ring) > 0u && !(emu_rd(base, EMU_UART_STATE) & EMU_UART_STATE_TXFULL);
}

static void background_pass(void) {
  const emu_mark_t m = prof_begin();
  can_rx_move();
  load_rx_move();
  fw_board_background(&g_board);
  g_port.can_tx_bytes += uart_tx(EMU_UART0_BASE, &g_port.can_tx);
  g_port.tel_tx_bytes += uart_tx(EMU_UART1_BASE, &g_port.tel_tx);
  (void)uart_tx(EMU_UART2_BASE, &g_load_tx);
  cost_add(&g_port.prof.background, prof_end(m), g_port.periods);
}

/** Sleep until an interrupt unless bytes wait (checked with interrupts masked:
 *  WFI still wakes on one pended meanwhile). */
static void idle(void) {
  const uint32_t pm = cm4_primask_save();
  const bool work = byte_ring_used(&g_port.can_rx) > 0u || byte_ring_used(&g_load_rx) > 0u ||
                    tx_ready(EMU_UART0_BASE, &g_port.can_tx) ||
                    tx_ready(EMU_UART1_BASE, &g_port.tel_tx) ||
                    tx_ready(EMU_UART2_BASE, &g_load_tx);
  if (!work) {
    cm4_wfi();
  }
  cm4_primask_restore(pm);
}

/* ---- start ------------------------------------------------------------------------ */

static void uart_init(uint32_t base, uint32_t ctrl) {
  emu_wr(base, EMU_UART_BAUDDIV, 16u);
  emu_wr(base, EMU_UART_INTSTATUS, EMU_UART_INT_RX | EMU_UART_INT_TX);
  emu_wr(base, EMU_UART_CTRL, ctrl);
}

static __attribute__((noreturn)) void refuse(const char *msg) {
  emu_sh_write0(msg);
  emu_sh_write0("\n");
  emu_sh_exit(2u);
}

int main(void) {
  static emu_boot_t boot; /* static: not on the stack */
  char msg[256];
  if (emu_boot_read((const uint8_t *)(uintptr_t)EMU_BOOT_ADDR, EMU_PSRAM_SIZE, &boot, msg,
                    sizeof msg) != 0) {
    refuse(msg);
  }
  if (sim_sizeof() > sizeof g_sim_mem) {
    emu_line_t l = {.n = 0u};
    emu_line_str(&l, "mps2_an386: the virtual motor needs ");
    emu_line_u32(&l, (uint32_t)sim_sizeof());
    emu_line_str(&l, " bytes, the image reserves ");
    emu_line_u32(&l, (uint32_t)sizeof g_sim_mem);
    emu_line_emit(&l);
    emu_sh_exit(2u);
  }
  /* the virtual motor */
  struct fw_port *p = &g_port;
  p->sim = sim_init_in(g_sim_mem, sizeof g_sim_mem, &boot.plant);
  if (p->sim == NULL) {
    refuse("emu boot block: sim_plant_params_t refused by sim_init_in");
  }
  sim_plant_state_t st;
  memset(&st, 0, sizeof st);
  st.x_m = boot.x0_m;
  sim_set_state(p->sim, &st);
  sim_set_load(p->sim, boot.load_N);
  p->f_pwm_int_Hz = (uint32_t)(boot.plant.f_pwm_Hz + 0.5);
  if (p->f_pwm_int_Hz == 0u) {
    p->f_pwm_int_Hz = 1u;
  }
  p->pwm_on = 0u;
  for (int j = 0; j < 3; ++j) {
    p->duty[j] = 0.5f;
  }
  /* the links */
  byte_ring_init(&p->can_rx, p->can_rx_buf, EMU_CAN_RX_LEN);
  byte_ring_init(&p->can_tx, p->can_tx_buf, EMU_CAN_TX_LEN);
  byte_ring_init(&p->tel_tx, p->tel_tx_buf, EMU_TEL_TX_LEN);
  byte_ring_init(&g_load_rx, g_load_rx_buf, EMU_LOAD_RX_LEN);
  byte_ring_init(&g_load_tx, g_load_tx_buf, EMU_LOAD_TX_LEN);
  const char version[5] = {'0', '1', (char)('0' + FW_VERSION_MINOR / 10),
                           (char)('0' + FW_VERSION_MINOR % 10), '\0'};
  slcan_init(&p->slcan, version, "E386");
  /* the flash page */
  p->has_nvm = emu_flash_init(&p->flash, boot.nvm_path) ? 1u : 0u;
  emu_flash_device(&p->flash, &p->page);
  /* the drive */
  const fw_status_t fst = fw_app_init(&g_app, &boot.cfg, boot.node_id);
  if (fst != FW_OK && fst != FW_ERR_SALIENCY) {
    refuse("emu boot block: fw_config_t refused by fw_app_init");
  }
  const fw_app_nvm_state_t nvm = fw_board_init(&g_board, &g_app, p);
  const sim_vmotor_lock_t lock = {NULL, plant_lock_enter, plant_lock_exit};
  (void)sim_vmotor_link_init(&g_link, p->sim, &boot.plant, boot.load_N, &lock);
  sim_vmotor_link_set_owner(&g_link, &p->overruns, board_stats, NULL);
  {
    emu_line_t l = {.n = 0u};
    emu_line_str(&l, "mps2_an386: drive node ");
    emu_line_u32(&l, boot.node_id);
    emu_line_str(&l, ", firmware " FW_VERSION_STRING ", f_pwm ");
    emu_line_u32(&l, p->f_pwm_int_Hz);
    emu_line_str(&l, " Hz, dilation ");
    emu_line_u32(&l, EMU_DILATION);
    emu_line_str(&l, ", flash ");
    emu_line_str(&l, p->has_nvm ? p->flash.path : "none");
    emu_line_str(&l, ", stored block state ");
    emu_line_u32(&l, (uint32_t)nvm);
    emu_line_emit(&l);
  }
  /* the hardware */
  uart_init(EMU_UART0_BASE, EMU_UART_CTRL_TXEN | EMU_UART_CTRL_RXEN | EMU_UART_CTRL_RXINTEN);
  uart_init(EMU_UART1_BASE, EMU_UART_CTRL_TXEN);
  uart_init(EMU_UART2_BASE, EMU_UART_CTRL_TXEN | EMU_UART_CTRL_RXEN | EMU_UART_CTRL_RXINTEN);
  cm4_irq_priority(EMU_IRQ_UART0_RX, CM4_PRIO(EMU_PRIO_UART_RX));
  cm4_irq_priority(EMU_IRQ_UART2_RX, CM4_PRIO(EMU_PRIO_UART_RX));
  cm4_irq_priority(EMU_IRQ_TIMER0, CM4_PRIO(EMU_PRIO_TIMER0));
  cm4_irq_priority(EMU_IRQ_CONTROL, CM4_PRIO(EMU_PRIO_CONTROL));
  cm4_pendsv_priority(CM4_PRIO(EMU_PRIO_SUPERVISION));
  emu_wr(EMU_TIMER1_BASE, EMU_TIMER_RELOAD, 0xFFFFFFFFu); /* free running */
  emu_wr(EMU_TIMER1_BASE, EMU_TIMER_VALUE, 0xFFFFFFFFu);
  emu_wr(EMU_TIMER1_BASE, EMU_TIMER_CTRL, EMU_TIMER_CTRL_EN);
  const uint32_t ticks =
      (uint32_t)((double)EMU_DILATION * (double)EMU_SYSCLK_HZ / boot.plant.f_pwm_Hz + 0.5);
  emu_wr(EMU_TIMER0_BASE, EMU_TIMER_RELOAD, ticks - 1u); /* the period is RELOAD + 1 ticks */
  emu_wr(EMU_TIMER0_BASE, EMU_TIMER_VALUE, ticks - 1u);
  emu_wr(EMU_TIMER0_BASE, EMU_TIMER_INTCLEAR, 1u);
  cm4_irq_enable(EMU_IRQ_CONTROL);
  cm4_irq_enable(EMU_IRQ_UART0_RX);
  cm4_irq_enable(EMU_IRQ_UART2_RX);
  cm4_irq_enable(EMU_IRQ_TIMER0);
  emu_wr(EMU_TIMER0_BASE, EMU_TIMER_CTRL, EMU_TIMER_CTRL_EN | EMU_TIMER_CTRL_IRQEN);
  for (;;) {
    background_pass();
    idle();
  }
}
