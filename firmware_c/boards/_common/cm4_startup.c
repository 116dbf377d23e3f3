/**
 * @file cm4_startup.c
 * @brief Reset handler and default handlers shared by the Cortex-M4F boards:
 *        the FPU switched on before any floating-point instruction (CPACR,
 *        ARMv7-M ARM B3.2.20), .data copied from its load address, .bss
 *        zeroed, then the board's main(). The vector table is the board's
 *        (its IRQ count is); it names these handlers.
 *
 * Linker symbols every board's script provides: __stack_top, __data_load,
 * __data_start, __data_end, __bss_start__, __bss_end__.
 */
#include <stdint.h>

#include "cm4.h"

extern uint32_t __data_load, __data_start, __data_end, __bss_start__, __bss_end__;
int main(void);
void cm4_reset_handler(void);
void cm4_default_handler(void);
void cm4_fault_handler(void);
void board_fatal(uint32_t code);

__attribute__((noreturn)) void cm4_reset_handler(void) {
  CM4_REG(CM4_SCB_CPACR) |= 0xFu << 20; /* CP10, CP11 full access */
  __asm volatile("dsb\n isb" ::: "memory");
  /* word loops: no library call before .bss is zero */
  const uint32_t *src = &__data_load;
  for (uint32_t *dst = &__data_start; dst < &__data_end;) {
    *dst++ = *src++;
  }
  for (uint32_t *dst = &__bss_start__; dst < &__bss_end__;) {
    *dst++ = 0u;
  }
  (void)main();
  board_fatal(0xDEADu); /* main returned */
  for (;;) {
  }
}

/** An interrupt nobody enabled. */
void cm4_default_handler(void) { board_fatal(0xBADu); }

/** HardFault, MemManage, BusFault, UsageFault: the board's fatal path. */
void cm4_fault_handler(void) { board_fatal(0xFA17u); }

void cm4_system_reset(void) {
  __asm volatile("dsb" ::: "memory");
  CM4_REG(CM4_SCB_AIRCR) = CM4_AIRCR_VECTKEY | (CM4_REG(CM4_SCB_AIRCR) & (7u << 8)) |
                           CM4_AIRCR_SYSRESETREQ;
  __asm volatile("dsb" ::: "memory");
  for (;;) {
  }
}
