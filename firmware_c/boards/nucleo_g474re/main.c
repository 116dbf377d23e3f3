/**
 * @file main.c
 * @brief NUCLEO-G474RE image: the drive application (fw_app) through the board
 *        glue (fw_board) over this board's port (g474_port.c), its vector table,
 *        interrupt handlers and fatal path. NOT YET TESTED ON SILICON.
 *
 * Boot: clocks (170 MHz) -> peripherals with the outputs off -> the drive's
 * configuration (defaults + this power stage's scaling and limits) ->
 * fw_app_init -> fw_board_init (boots from the parameter page) -> interrupts,
 * PWM counter, watchdog -> the background loop, which kicks the watchdog
 * after each pass.
 */
#include <stdint.h>

#include "cm4.h"
#include "g474_calc.h"
#include "g474_pinmap.h"
#include "g474_port.h"
#include "g474_regs.h"
#include "pmlsm/fw_app.h"
#include "pmlsm/fw_board.h"

/* application-owned instances (the core has no globals) */
static fw_app_t g_app;
static fw_board_t g_board;
static fw_port_t g_port;
static uint32_t g_port_ready; /* the NMI may come before g474_port_init */

/** The last board_fatal code, kept over the reset it causes (.noinit: not
 *  zeroed by the start-up); read it with the debugger. */
__attribute__((section(".noinit"))) volatile uint32_t g474_last_fatal;

void board_fatal(uint32_t code);
void g474_adc_handler(void);
void g474_pendsv_handler(void);
void g474_can_handler(void);
void g474_brk_handler(void);
void g474_dma_handler(void);
void g474_nmi_handler(void);
void cm4_reset_handler(void);
void cm4_default_handler(void);
void cm4_fault_handler(void);

/** Outputs off at once, the code kept, then: a halt at a breakpoint when a
 *  debugger is attached (the state stays for inspection), otherwise a system
 *  reset (AIRCR.SYSRESETREQ): the drive boots again with the outputs off and
 *  the bench sees its boot-up message. */
__attribute__((noreturn)) void board_fatal(uint32_t code) {
  __asm volatile("cpsid i" ::: "memory");
  g474_outputs_off();
  g474_last_fatal = code;
  if ((CM4_REG(CM4_DHCSR) & CM4_DHCSR_C_DEBUGEN) != 0u) {
    __asm volatile("bkpt #0");
  }
  cm4_system_reset();
  for (;;) {
  }
}

/** ADC1 end of injected sequence: the control interrupt (fw_board_control_isr). */
void g474_adc_handler(void) {
  const uint32_t t0 = g474_cycles();
  if (g474_adc_irq_ack(&g_port)) {
    fw_board_control_isr(&g_board);
  }
  g474_isr_cycles(&g_port, t0);
}

/** PendSV: the supervision interrupt, pended by the control interrupt. */
void g474_pendsv_handler(void) {
  fw_board_supervision_isr(&g_board);
}

/** FDCAN1 line 0: receive FIFO 0 into the application's queue. */
void g474_can_handler(void) {
  g474_can_rx_irq(&g_port, &g_board);
}

/** TIM1 break (shared with TIM15, unused): the hardware trip. */
void g474_brk_handler(void) {
  g474_brk_irq(&g_port);
}

/** DMA1 channel 1: the serial link's chunk went out. */
void g474_dma_handler(void) {
  g474_uart_dma_irq(&g_port);
}

/** NMI: a double ECC error (the parameter page's is handled, any other is
 *  fatal), the clock security system, or anything else (fatal). */
void g474_nmi_handler(void) {
  g474_nmi(g_port_ready != 0u ? &g_port : NULL);
}

/* ---- vector table (RM0440, "Interrupt and exception vectors": 16 core
 *      vectors, then IRQ 0..101) ---- */

extern uint32_t __stack_top;
typedef void (*g474_vector_t)(void);
typedef struct {
  uint32_t *sp;
  g474_vector_t v[15u + G4_IRQ_COUNT];
} g474_vectors_t;

/* clang-format off */
#define D cm4_default_handler /* an interrupt nobody enabled: board_fatal(0xBAD) */
/* IRQ 11 DMA1 channel 1, 18 ADC1_2, 21 FDCAN1_IT0, 24 TIM1_BRK_TIM15 */
__attribute__((section(".isr_vector"), used)) const g474_vectors_t g474_vectors = {
    &__stack_top,
    {
        cm4_reset_handler,   /* 1 reset */
        g474_nmi_handler,    /* 2 NMI */
        cm4_fault_handler,   /* 3 HardFault */
        cm4_fault_handler,   /* 4 MemManage */
        cm4_fault_handler,   /* 5 BusFault */
        cm4_fault_handler,   /* 6 UsageFault */
        0, 0, 0, 0,          /* 7..10 reserved */
        cm4_default_handler, /* 11 SVCall */
        cm4_default_handler, /* 12 DebugMonitor */
        0,                   /* 13 reserved */
        g474_pendsv_handler, /* 14 PendSV: the supervision interrupt */
        cm4_default_handler, /* 15 SysTick */
        D, D, D, D, D, D, D, D, /* IRQ 0..7 */
        D, D, D,                /* IRQ 8..10 */
        g474_dma_handler,    /* IRQ 11 */
        D, D, D, D, D, D,       /* IRQ 12..17 */
        g474_adc_handler,    /* IRQ 18 */
        D, D,                   /* IRQ 19..20 */
        g474_can_handler,    /* IRQ 21 */
        D, D,                   /* IRQ 22..23 */
        g474_brk_handler,    /* IRQ 24 */
        D, D, D, D, D, D, D, D, /* IRQ 25..32 */
        D, D, D, D, D, D, D, D, /* IRQ 33..40 */
        D, D, D, D, D, D, D, D, /* IRQ 41..48 */
        D, D, D, D, D, D, D, D, /* IRQ 49..56 */
        D, D, D, D, D, D, D, D, /* IRQ 57..64 */
        D, D, D, D, D, D, D, D, /* IRQ 65..72 */
        D, D, D, D, D, D, D, D, /* IRQ 73..80 */
        D, D, D, D, D, D, D, D, /* IRQ 81..88 */
        D, D, D, D, D, D, D, D, /* IRQ 89..96 */
        D, D, D, D, D,          /* IRQ 97..101 */
    },
};
#undef D
/* clang-format on */
_Static_assert(sizeof(g474_vectors_t) == 4u * (16u + G4_IRQ_COUNT), "vector table size");

int main(void) {
  CM4_REG(CM4_SCB_VTOR) = (uint32_t)(uintptr_t)&g474_vectors;
  g474_clock_init();
  g474_port_init(&g_port);
  g_port_ready = 1u;
  fw_config_t cfg;
  fw_config_default(&cfg);
  g474_board_config(&cfg, G474_ADC_OVERSAMPLE);
  (void)fw_app_init(&g_app, &cfg, (uint8_t)G474_NODE_ID);
  /* lock = the port's critical section; boot from the parameter page */
  (void)fw_board_init(&g_board, &g_app, &g_port);
  g474_port_start(&g_port);
  for (;;) {
    fw_board_background(&g_board);
    g474_iwdg_kick(); /* only here: a stuck background stops it */
  }
}
