/**
 * @file startup.c
 * @brief Bare-metal start for the Cortex-M4F instruction-count harness
 *        (QEMU mps2-an386). Vector table, FPU enable (CPACR), then newlib's
 *        rdimon crt0 (_start), which zeroes .bss, sets up semihosting stdio
 *        and argv, and calls main().
 */
#include <stdint.h>

extern uint32_t __stack_top;
extern void _start(void);
void Reset_Handler(void);
void Fault_Handler(void);

__attribute__((naked, noreturn)) void Reset_Handler(void) {
  __asm volatile(
      "ldr r0, =0xE000ED88\n" /* CPACR: full access to CP10/CP11 (the FPU) */
      "ldr r1, [r0]\n"
      "orr r1, r1, #(0xF << 20)\n"
      "str r1, [r0]\n"
      "dsb\n"
      "isb\n"
      "ldr r0, =__stack_top\n"
      "mov sp, r0\n"
      "b _start\n");
}

/* Any fault: report through semihosting SYS_EXIT with a non-zero code. */
__attribute__((naked, noreturn)) void Fault_Handler(void) {
  __asm volatile(
      "mov r0, #0x18\n"           /* SYS_EXIT */
      "ldr r1, =0x20024\n"        /* ADP_Stopped_RunTimeErrorUnknown */
      "bkpt 0xAB\n"
      "b .\n");
}

__attribute__((section(".vectors"), used)) const uintptr_t g_vectors[16] = {
    (uintptr_t)&__stack_top,     (uintptr_t)Reset_Handler, (uintptr_t)Fault_Handler,
    (uintptr_t)Fault_Handler,    (uintptr_t)Fault_Handler, (uintptr_t)Fault_Handler,
    (uintptr_t)Fault_Handler,    0, 0, 0, 0,
    (uintptr_t)Fault_Handler,    (uintptr_t)Fault_Handler, 0,
    (uintptr_t)Fault_Handler,    (uintptr_t)Fault_Handler};
