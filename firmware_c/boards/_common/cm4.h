/**
 * @file cm4.h
 * @brief Cortex-M4 core registers every board port uses: NVIC, SCB (PendSV,
 *        priorities, reset), the interrupt masks. Facts from the ARMv7-M
 *        Architecture Reference Manual (DDI 0403E), B3.2 (System control
 *        block) and B3.4 (NVIC); no vendor header needed.
 *
 * Priorities: the boards use the top four bits (an STM32G4 implements four,
 * QEMU's NVIC eight), written as (level << 4); lower is more urgent.
 */
#ifndef PMLSM_BOARD_CM4_H
#define PMLSM_BOARD_CM4_H

#include <stdint.h>

#define CM4_REG(addr) (*(volatile uint32_t *)(uintptr_t)(addr))
#define CM4_REG8(addr) (*(volatile uint8_t *)(uintptr_t)(addr))

/* SCB (B3.2.2) */
#define CM4_SCB_ICSR 0xE000ED04u  /**< interrupt control and state */
#define CM4_SCB_VTOR 0xE000ED08u  /**< vector table offset */
#define CM4_SCB_AIRCR 0xE000ED0Cu /**< application interrupt and reset control */
#define CM4_SCB_SCR 0xE000ED10u   /**< system control (SLEEPONEXIT, SLEEPDEEP) */
#define CM4_SCB_SHPR3 0xE000ED20u /**< priorities of PendSV (23:16) and SysTick (31:24) */
#define CM4_SCB_CPACR 0xE000ED88u /**< coprocessor access (CP10, CP11: the FPU) */
#define CM4_ICSR_PENDSVSET (1u << 28)
#define CM4_AIRCR_VECTKEY (0x05FAu << 16)
#define CM4_AIRCR_SYSRESETREQ (1u << 2)
/* NVIC (B3.4.3) */
#define CM4_NVIC_ISER 0xE000E100u /**< set-enable, one bit per IRQ, 32 per word */
#define CM4_NVIC_ICER 0xE000E180u /**< clear-enable */
#define CM4_NVIC_ISPR 0xE000E200u /**< set-pending */
#define CM4_NVIC_ICPR 0xE000E280u /**< clear-pending */
#define CM4_NVIC_IPR 0xE000E400u  /**< priority, one byte per IRQ */

/** Priority level (0 most urgent .. 15) as the register byte. */
#define CM4_PRIO(level) ((uint8_t)((level) << 4))

static inline void cm4_irq_enable(uint32_t irq) {
  CM4_REG(CM4_NVIC_ISER + 4u * (irq >> 5)) = 1u << (irq & 31u);
}
static inline void cm4_irq_disable(uint32_t irq) {
  CM4_REG(CM4_NVIC_ICER + 4u * (irq >> 5)) = 1u << (irq & 31u);
}
static inline void cm4_irq_pend(uint32_t irq) {
  CM4_REG(CM4_NVIC_ISPR + 4u * (irq >> 5)) = 1u << (irq & 31u);
}
static inline void cm4_irq_unpend(uint32_t irq) {
  CM4_REG(CM4_NVIC_ICPR + 4u * (irq >> 5)) = 1u << (irq & 31u);
}
static inline void cm4_irq_priority(uint32_t irq, uint8_t prio) {
  CM4_REG8(CM4_NVIC_IPR + irq) = prio;
}
static inline void cm4_pendsv_priority(uint8_t prio) {
  CM4_REG(CM4_SCB_SHPR3) = (CM4_REG(CM4_SCB_SHPR3) & ~(0xFFu << 16)) | ((uint32_t)prio << 16);
}
/** Pend PendSV: the supervision interrupt of every board. */
static inline void cm4_pendsv_set(void) { CM4_REG(CM4_SCB_ICSR) = CM4_ICSR_PENDSVSET; }

#if defined(__arm__)
static inline uint32_t cm4_basepri_get(void) {
  uint32_t v;
  __asm volatile("mrs %0, basepri" : "=r"(v));
  return v;
}
static inline void cm4_basepri_set(uint32_t v) { __asm volatile("msr basepri, %0" ::"r"(v) : "memory"); }
/** Raise BASEPRI to prio (never lowers it: BASEPRI_MAX). */
static inline void cm4_basepri_max(uint32_t prio) {
  __asm volatile("msr basepri_max, %0" ::"r"(prio) : "memory");
}
static inline uint32_t cm4_primask_save(void) {
  uint32_t v;
  __asm volatile("mrs %0, primask\n cpsid i" : "=r"(v)::"memory");
  return v;
}
static inline void cm4_primask_restore(uint32_t v) { __asm volatile("msr primask, %0" ::"r"(v) : "memory"); }
static inline void cm4_wfi(void) { __asm volatile("wfi" ::: "memory"); }

/** The drive's critical section on every board (fw_port_critical_enter/exit): BASEPRI
 *  raised to the control interrupt's level, so the background's changes of the core
 *  never race the control and supervision interrupts, while more urgent ones (a power
 *  stage's break, an emulated board's hardware model) stay live. The key is the BASEPRI
 *  before: sections nest. */
static inline uint32_t cm4_critical_enter(uint32_t control_level) {
  const uint32_t key = cm4_basepri_get();
  cm4_basepri_max(CM4_PRIO(control_level));
  return key;
}
static inline void cm4_critical_exit(uint32_t key) { cm4_basepri_set(key); }
static inline void cm4_dsb(void) { __asm volatile("dsb" ::: "memory"); }
static inline void cm4_isb(void) { __asm volatile("isb" ::: "memory"); }
#endif

/** Request a system reset (AIRCR.SYSRESETREQ); does not return. */
void cm4_system_reset(void);

#endif /* PMLSM_BOARD_CM4_H */
