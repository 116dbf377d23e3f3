/**
 * @file g474_port.c
 * @brief fw_port.h on the NUCLEO-G474RE (STM32G474RET6) with a three-shunt
 *        power stage on its morpho connectors (g474_pinmap.h).
 *        NOT YET TESTED ON SILICON: written from RM0440 and the board's user
 *        manual UM2505; the numbers come from g474_calc.c, which the host tests
 *        check against the manual's formulas (tests/c/test_g474_calc.c).
 *
 * The period (24 kHz, TIM1 centre-aligned): the counter runs 0 -> ARR -> 0;
 * the phase outputs are active (high side on) while CNT < CCR, so the low
 * sides conduct around the counter's peak. Both ADCs sample the currents
 * there (TRGO2 = OC4REF a few ticks before the peak so that the samples are
 * centred on it); the end of ADC1's injected sequence is the control
 * interrupt; the duties it writes are preloaded and the update event, on the
 * peak (repetition counter 1), loads them: samples of period k, duties in
 * period k + 1, as the drive's model has it. The supervision (PendSV) runs
 * right after, before the next peak.
 */
#include "g474_port.h"

#include <string.h>

#include "cm4.h"
#include "g474_calc.h"
#include "g474_pinmap.h"
#include "g474_regs.h"
#include "pmlsm/fw_enums.h"

void board_fatal(uint32_t code);

#define TIM1 G4_TIM1_BASE
#define TIM2 G4_TIM2_BASE
#define ADC1 G4_ADC1_BASE
#define ADC2 G4_ADC2_BASE
#define RCC G4_RCC_BASE
#define FLASHR G4_FLASHR_BASE
#define CAN G4_FDCAN1_BASE
#define CANRAM G4_SRAMCAN_BASE /* FDCAN1's section is the first */
#define UART G4_LPUART1_BASE
#define DMA G4_DMA1_BASE
#define DMA_CH 1u

/* ---- time: the DWT cycle counter (ARMv7-M ARM, "The Data Watchpoint and Trace unit") ---- */
#define DWT_CTRL 0xE0001000u
#define DWT_CYCCNT 0xE0001004u
#define DEMCR 0xE000EDFCu

uint32_t g474_cycles(void) {
  return CM4_REG(DWT_CYCCNT);
}

static void delay_cycles(uint32_t n) {
  const uint32_t t0 = g474_cycles();
  while (g474_cycles() - t0 < n) {
  }
}

/** Cycles of `us` microseconds at SYSCLK (170 MHz) and before the switch (HSI 16 MHz). */
#define US(us) ((us) * (G474_SYSCLK_HZ / 1000000u))
#define US_HSI(us) ((us) * 16u)

static void delay_us(uint32_t us) {
  delay_cycles(US(us));
}

/** Wait until (reg & mask) == want, at most `limit` core cycles. */
static bool wait_bits(uint32_t addr, uint32_t mask, uint32_t want, uint32_t limit) {
  const uint32_t t0 = g474_cycles();
  while ((CM4_REG(addr) & mask) != want) {
    if (g474_cycles() - t0 > limit) {
      return false;
    }
  }
  return true;
}

/* ---- clocks (RM0440 "Reset and clock control", "Power control": dynamic
 *      voltage scaling, range 1 boost mode) ---- */

void g474_clock_init(void) {
  CM4_REG(DEMCR) |= 1u << 24; /* TRCENA: the cycle counter for the delays */
  CM4_REG(DWT_CYCCNT) = 0u;
  CM4_REG(DWT_CTRL) |= 1u;
  g474_clock_plan_t plan;
  if (!g474_clock_plan(G474_HSE_HZ, G474_SYSCLK_HZ, &plan) || plan.flash_ws > 4u) {
    board_fatal(G474_FATAL_CONFIG);
  }
  CM4_REG(RCC + RCC_APB1ENR1) |= RCC_APB1ENR1_PWREN;
  (void)CM4_REG(RCC + RCC_APB1ENR1);
  /* HSE: the 24 MHz crystal (not bypass) */
  CM4_REG(RCC + RCC_CR) |= RCC_CR_HSEON;
  /* the 16 MHz HSI clocks the core until the switch: 100 ms */
  if (!wait_bits(G4_RCC_BASE + RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY, US_HSI(100000u))) {
    board_fatal(G474_FATAL_CLOCK);
  }
  /* range 1 (VOS = 01) with boost (R1MODE = 0) for 150 < SYSCLK <= 170 MHz; the
     switch to boost with HCLK divided by 2 first, back to /1 after 1 us */
  CM4_REG(RCC + RCC_CFGR) =
      (CM4_REG(RCC + RCC_CFGR) & ~(0xFu << RCC_CFGR_HPRE_POS)) | (0x8u << RCC_CFGR_HPRE_POS);
  CM4_REG(G4_PWR_BASE + PWR_CR1) =
      (CM4_REG(G4_PWR_BASE + PWR_CR1) & ~(3u << PWR_CR1_VOS_POS)) | (1u << PWR_CR1_VOS_POS);
  (void)wait_bits(G4_PWR_BASE + PWR_SR2, PWR_SR2_VOSF, 0u, US_HSI(1000u));
  if (plan.boost) {
    CM4_REG(G4_PWR_BASE + PWR_CR5) &= ~PWR_CR5_R1MODE;
  }
  /* wait states before the faster clock; prefetch, instruction and data caches */
  CM4_REG(FLASHR + FLASH_ACR) = (CM4_REG(FLASHR + FLASH_ACR) & ~0xFu) | plan.flash_ws |
                                FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
  if ((CM4_REG(FLASHR + FLASH_ACR) & 0xFu) != plan.flash_ws) {
    board_fatal(G474_FATAL_CLOCK);
  }
  /* PLL: HSE / M x N / R, only the R output */
  CM4_REG(RCC + RCC_CR) &= ~RCC_CR_PLLON;
  (void)wait_bits(G4_RCC_BASE + RCC_CR, RCC_CR_PLLRDY, 0u, US_HSI(1000u));
  CM4_REG(RCC + RCC_PLLCFGR) = plan.pllcfgr;
  CM4_REG(RCC + RCC_CR) |= RCC_CR_PLLON;
  if (!wait_bits(G4_RCC_BASE + RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY, US_HSI(10000u))) {
    board_fatal(G474_FATAL_CLOCK);
  }
  /* APB1 = APB2 = HCLK (PPRE 0xx); switch to the PLL (SW = 11) */
  CM4_REG(RCC + RCC_CFGR) =
      (CM4_REG(RCC + RCC_CFGR) & ~((7u << RCC_CFGR_PPRE1_POS) | (7u << RCC_CFGR_PPRE2_POS) | 3u)) |
      3u;
  if (!wait_bits(G4_RCC_BASE + RCC_CFGR, 3u << RCC_CFGR_SWS_POS, 3u << RCC_CFGR_SWS_POS,
                 US_HSI(10000u))) {
    board_fatal(G474_FATAL_CLOCK);
  }
  delay_cycles(170u); /* at least 1 us at HCLK = 85 MHz */
  CM4_REG(RCC + RCC_CFGR) &= ~(0xFu << RCC_CFGR_HPRE_POS);
  /* the clock security system: an HSE failure switches to HSI and raises the NMI */
  CM4_REG(RCC + RCC_CR) |= RCC_CR_CSSON;
}

/* ---- GPIO (RM0440 "General-purpose I/Os") ---- */

enum { PIN_AF = 2u, PIN_ANALOG = 3u, PIN_OUT = 1u, PIN_IN = 0u };

static void pin_mode(uint32_t port, uint32_t pin, uint32_t mode, uint32_t af, uint32_t pull) {
  const uint32_t g = G4_GPIO_BASE(port);
  CM4_REG(RCC + RCC_AHB2ENR) |= RCC_AHB2ENR_GPIOEN(port);
  (void)CM4_REG(RCC + RCC_AHB2ENR);
  const uint32_t afr = pin < 8u ? GPIO_AFRL : GPIO_AFRH;
  const uint32_t sh4 = 4u * (pin & 7u);
  CM4_REG(g + afr) = (CM4_REG(g + afr) & ~(0xFu << sh4)) | ((af & 0xFu) << sh4);
  CM4_REG(g + GPIO_OSPEEDR) |= 3u << (2u * pin); /* very high: PWM and CAN edges */
  CM4_REG(g + GPIO_PUPDR) = (CM4_REG(g + GPIO_PUPDR) & ~(3u << (2u * pin))) | (pull << (2u * pin));
  CM4_REG(g + GPIO_MODER) = (CM4_REG(g + GPIO_MODER) & ~(3u << (2u * pin))) | (mode << (2u * pin));
}

/* the six gate inputs as GPIO outputs at their off level */
static void gate_pin_off(uint32_t port, uint32_t pin, uint32_t active_low) {
  const uint32_t g = G4_GPIO_BASE(port);
  CM4_REG(g + 0x18u) = active_low ? (1u << pin) : (1u << (pin + 16u)); /* BSRR */
  CM4_REG(g + GPIO_MODER) =
      (CM4_REG(g + GPIO_MODER) & ~(3u << (2u * pin))) | (PIN_OUT << (2u * pin));
}

void g474_outputs_off(void) {
  /* the timer's outputs (idle levels: all switches open) ... */
  CM4_REG(TIM1 + TIM_BDTR) &= ~TIM_BDTR_MOE;
  /* ... and the pins themselves, whatever the timer's state (clocks may be off:
     the GPIO enables are set first) */
  CM4_REG(RCC + RCC_AHB2ENR) |=
      RCC_AHB2ENR_GPIOEN(G474_PA) | RCC_AHB2ENR_GPIOEN(G474_PB) | RCC_AHB2ENR_GPIOEN(G474_PC);
  (void)CM4_REG(RCC + RCC_AHB2ENR);
  gate_pin_off(G474_PWM_UH_PORT, G474_PWM_UH_PIN, G474_PWM_HS_ACTIVE_LOW);
  gate_pin_off(G474_PWM_VH_PORT, G474_PWM_VH_PIN, G474_PWM_HS_ACTIVE_LOW);
  gate_pin_off(G474_PWM_WH_PORT, G474_PWM_WH_PIN, G474_PWM_HS_ACTIVE_LOW);
  gate_pin_off(G474_PWM_UL_PORT, G474_PWM_UL_PIN, G474_PWM_LS_ACTIVE_LOW);
  gate_pin_off(G474_PWM_VL_PORT, G474_PWM_VL_PIN, G474_PWM_LS_ACTIVE_LOW);
  gate_pin_off(G474_PWM_WL_PORT, G474_PWM_WL_PIN, G474_PWM_LS_ACTIVE_LOW);
}

/* ---- PWM: TIM1 (RM0440 "Advanced-control timers (TIM1/TIM8/TIM20)") ---- */

static g474_adc_timing_t adc_timing(void) {
  /* ADC clock HCLK / 4 = 42.5 MHz, synchronous (no trigger jitter); 6.5-cycle
     sampling, 12.5-cycle 12-bit conversion; trigger latency taken as 3 ADC
     cycles (to be measured: docs/hardware_bringup.md) */
  const g474_adc_timing_t t = {G474_SYSCLK_HZ, 4u, 13u, 25u, 6u, G474_ADC_OVERSAMPLE};
  return t;
}

static void pwm_init(fw_port_t *port, uint32_t f_pwm_Hz) {
  CM4_REG(RCC + RCC_APB2ENR) |= RCC_APB2ENR_TIM1EN;
  (void)CM4_REG(RCC + RCC_APB2ENR);
  const uint32_t arr = g474_pwm_arr(G474_SYSCLK_HZ, f_pwm_Hz);
  const g474_adc_timing_t at = adc_timing();
  const uint32_t trig = g474_adc_trigger_ticks(&at);
  if (arr < 2u * trig || arr > 0xFFFFu) {
    board_fatal(G474_FATAL_CONFIG);
  }
  port->arr = arr;
  port->ccr_half = arr / 2u;
  CM4_REG(TIM1 + TIM_CR1) = (1u << TIM_CR1_CMS_POS) | TIM_CR1_ARPE; /* centre-aligned 1, stopped */
  CM4_REG(TIM1 + TIM_PSC) = 0u;
  CM4_REG(TIM1 + TIM_ARR) = arr;
  CM4_REG(TIM1 + TIM_RCR) = 1u; /* one update event per period (every other extremum) */
  CM4_REG(TIM1 + TIM_CCMR1) =
      TIM_CCMR_OCM_PWM1(0u) | TIM_CCMR_OCPE(0u) | TIM_CCMR_OCM_PWM1(1u) | TIM_CCMR_OCPE(1u);
  /* channel 3: phase W; channel 4: PWM mode 2, rising at CNT = CCR4 counting up */
  CM4_REG(TIM1 + TIM_CCMR2) =
      TIM_CCMR_OCM_PWM1(0u) | TIM_CCMR_OCPE(0u) | TIM_CCMR_OCM_PWM2(1u) | TIM_CCMR_OCPE(1u);
  CM4_REG(TIM1 + TIM_CCR1) = port->ccr_half;
  CM4_REG(TIM1 + TIM_CCR2) = port->ccr_half;
  CM4_REG(TIM1 + TIM_CCR3) = port->ccr_half;
  CM4_REG(TIM1 + TIM_CCR4) = arr - trig;
  uint32_t ccer = 0u;
  for (uint32_t ch = 1u; ch <= 3u; ch++) {
    ccer |= TIM_CCER_CCE(ch) | TIM_CCER_CCNE(ch);
    ccer |= G474_PWM_HS_ACTIVE_LOW ? TIM_CCER_CCP(ch) : 0u;
    ccer |= G474_PWM_LS_ACTIVE_LOW ? TIM_CCER_CCNP(ch) : 0u;
  }
  CM4_REG(TIM1 + TIM_CCER) = ccer;
  /* TRGO2 = OC4REF (ADC trigger), TRGO = OC4REF (TIM2 latches the scale on it);
     idle levels with MOE = 0: every gate input at its off level */
  uint32_t cr2 = (7u << TIM_CR2_MMS2_POS) | (7u << TIM_CR2_MMS_POS);
  for (uint32_t ch = 0u; ch < 3u; ch++) {
    cr2 |= (G474_PWM_HS_ACTIVE_LOW ? TIM_CR2_OIS1 : 0u) << (2u * ch);
    cr2 |= (G474_PWM_LS_ACTIVE_LOW ? TIM_CR2_OIS1N : 0u) << (2u * ch);
  }
  CM4_REG(TIM1 + TIM_CR2) = cr2;
  /* break input from the pin (AF1.BKINE), polarity in BDTR.BKP */
  CM4_REG(TIM1 + TIM_AF1) = TIM_AF1_BKINE;
  const uint8_t dtg = g474_dead_time_dtg(G474_DEAD_TIME_NS, G474_SYSCLK_HZ, NULL);
  /* dead time, off-state selection in run and idle, break enabled with its
     polarity and an 8-sample filter at 170 MHz (47 ns), no automatic output
     enable, MOE = 0; LOCK level 1 freezes DTG, BKE, BKP, AOE, OISx from here */
  CM4_REG(TIM1 + TIM_BDTR) = (uint32_t)dtg | TIM_BDTR_OSSI | TIM_BDTR_OSSR | TIM_BDTR_BKE |
                             (G474_BKIN_ACTIVE_LOW ? 0u : TIM_BDTR_BKP) | (3u << TIM_BDTR_BKF_POS) |
                             (1u << TIM_BDTR_LOCK_POS);
  CM4_REG(TIM1 + TIM_EGR) = TIM_EGR_UG; /* load ARR, RCR, CCRx from their preloads */
  CM4_REG(TIM1 + TIM_SR) = 0u;
  CM4_REG(TIM1 + TIM_DIER) = TIM_DIER_BIE;
  /* a halted core stops TIM1 with its outputs disabled */
  CM4_REG(G4_DBGMCU_BASE + DBGMCU_APB2FZ) |= DBGMCU_APB2FZ_TIM1;
  pin_mode(G474_PWM_UH_PORT, G474_PWM_UH_PIN, PIN_AF, G474_PWM_AF, 0u);
  pin_mode(G474_PWM_VH_PORT, G474_PWM_VH_PIN, PIN_AF, G474_PWM_AF, 0u);
  pin_mode(G474_PWM_WH_PORT, G474_PWM_WH_PIN, PIN_AF, G474_PWM_AF, 0u);
  pin_mode(G474_PWM_UL_PORT, G474_PWM_UL_PIN, PIN_AF, G474_PWM_AF, 0u);
  pin_mode(G474_PWM_VL_PORT, G474_PWM_VL_PIN, PIN_AF, G474_PWM_AF, 0u);
  pin_mode(G474_PWM_WL_PORT, G474_PWM_WL_PIN, PIN_AF, G474_PWM_AF, 0u);
  pin_mode(G474_BKIN_PORT, G474_BKIN_PIN, PIN_AF, G474_BKIN_AF, G474_BKIN_ACTIVE_LOW ? 1u : 2u);
}

/* Start the counter with its update event on the peak: one event per period
 * (RCR = 1) falls on the overflow when RCR was loaded before the counter
 * started (RM0440, "Repetition counter": odd RCR in centre-aligned mode). Checked
 * here by the counting direction right after the event (down after the peak),
 * and moved by half a period if it is not (RCR = 0 for one event). */
static bool pwm_update_on_peak(void) {
  const uint32_t period_us = 100u; /* two periods at 24 kHz */
  CM4_REG(TIM1 + TIM_SR) = ~TIM_SR_UIF;
  if (!wait_bits(TIM1 + TIM_SR, TIM_SR_UIF, TIM_SR_UIF, US(period_us))) {
    return false;
  }
  return (CM4_REG(TIM1 + TIM_CR1) & TIM_CR1_DIR) != 0u;
}

static void pwm_start(void) {
  CM4_REG(TIM1 + TIM_CR1) |= TIM_CR1_CEN;
  for (int attempt = 0; attempt < 3; attempt++) {
    if (pwm_update_on_peak()) {
      return;
    }
    /* on a valley: the next event reloads RCR = 0 (event on the next extremum,
       the peak), which reloads RCR = 1 again */
    CM4_REG(TIM1 + TIM_RCR) = 0u;
    CM4_REG(TIM1 + TIM_SR) = ~TIM_SR_UIF;
    (void)wait_bits(TIM1 + TIM_SR, TIM_SR_UIF, TIM_SR_UIF, US(100u));
    CM4_REG(TIM1 + TIM_RCR) = 1u;
  }
  board_fatal(G474_FATAL_PWM_PHASE);
}

void fw_port_pwm_write(fw_port_t *port, const float duty_abc[3], bool enable) {
  if (!enable) {
    CM4_REG(TIM1 + TIM_BDTR) &= ~TIM_BDTR_MOE; /* outputs to their idle levels now */
    CM4_REG(TIM1 + TIM_CCR1) = port->ccr_half; /* equal duties when they come back */
    CM4_REG(TIM1 + TIM_CCR2) = port->ccr_half;
    CM4_REG(TIM1 + TIM_CCR3) = port->ccr_half;
    return;
  }
  const uint32_t arr = port->arr;
  CM4_REG(TIM1 + TIM_CCR1) = g474_pwm_compare(duty_abc[0], arr); /* preloaded: next period */
  CM4_REG(TIM1 + TIM_CCR2) = g474_pwm_compare(duty_abc[1], arr);
  CM4_REG(TIM1 + TIM_CCR3) = g474_pwm_compare(duty_abc[2], arr);
  if ((CM4_REG(TIM1 + TIM_BDTR) & TIM_BDTR_MOE) == 0u &&
      atomic_load_explicit(&port->brk_latched, memory_order_relaxed) == 0u) {
    /* enable: re-arm the break interrupt, then the outputs (hardware keeps MOE
       cleared while the break input is active) */
    CM4_REG(TIM1 + TIM_SR) = ~TIM_SR_BIF;
    CM4_REG(TIM1 + TIM_DIER) |= TIM_DIER_BIE;
    CM4_REG(TIM1 + TIM_BDTR) |= TIM_BDTR_MOE;
  }
}

void g474_brk_irq(fw_port_t *port) {
  if ((CM4_REG(TIM1 + TIM_SR) & TIM_SR_BIF) != 0u) {
    /* MOE is already cleared by hardware; record the trip once, and stop this
       interrupt while the input may stay active (re-armed by the next enable) */
    CM4_REG(TIM1 + TIM_DIER) &= ~TIM_DIER_BIE;
    CM4_REG(TIM1 + TIM_SR) = ~TIM_SR_BIF;
    atomic_store_explicit(&port->brk_latched, 1u, memory_order_relaxed);
    port->brk_count++;
  }
}

uint16_t fw_port_hw_fault(fw_port_t *port) {
  if (atomic_load_explicit(&port->brk_latched, memory_order_relaxed) == 0u) {
    return 0u;
  }
  atomic_store_explicit(&port->brk_latched, 0u, memory_order_relaxed);
  return (uint16_t)FW_FAULT_POWER_STAGE_BREAK;
}

void fw_port_supervision_pend(fw_port_t *port) {
  (void)port;
  cm4_pendsv_set();
}

/* ---- ADC1 / ADC2 (RM0440 "Analog-to-digital converters (ADC)") ---- */

static void adc_enable(uint32_t adc, const uint8_t ch[2], bool irq) {
  CM4_REG(adc + ADC_CR) = 0u; /* leave deep power-down */
  CM4_REG(adc + ADC_CR) = ADC_CR_ADVREGEN;
  delay_us(25u); /* regulator start-up, 20 us */
  CM4_REG(adc + ADC_DIFSEL) = 0u;
  CM4_REG(adc + ADC_CR) = ADC_CR_ADVREGEN | ADC_CR_ADCAL; /* single-ended calibration */
  if (!wait_bits(adc + ADC_CR, ADC_CR_ADCAL, 0u, US(1000u))) {
    board_fatal(G474_FATAL_ADC);
  }
  delay_us(1u); /* >= 4 ADC cycles between calibration and enable */
  /* injected queue off (JSQR stays), 12-bit right-aligned; sampling 6.5 cycles */
  CM4_REG(adc + ADC_CFGR) = ADC_CFGR_JQDIS;
  CM4_REG(adc + ADC_CFGR2) =
      G474_ADC_OVERSAMPLE == 4u
          ? (ADC_CFGR2_JOVSE | (1u << ADC_CFGR2_OVSR_POS) | (1u << ADC_CFGR2_OVSS_POS))
          : 0u;
  uint32_t smpr1 = 0u;
  for (uint32_t i = 0u; i < 2u; i++) {
    smpr1 |= 1u << (3u * ch[i]); /* 001: 6.5 cycles; channels 0..9 are in SMPR1 */
  }
  CM4_REG(adc + ADC_SMPR1) = smpr1;
  CM4_REG(adc + ADC_ISR) = ADC_ISR_ADRDY;
  CM4_REG(adc + ADC_CR) = ADC_CR_ADVREGEN | ADC_CR_ADEN;
  if (!wait_bits(adc + ADC_ISR, ADC_ISR_ADRDY, ADC_ISR_ADRDY, US(1000u))) {
    board_fatal(G474_FATAL_ADC);
  }
  CM4_REG(adc + ADC_JSQR) = g474_adc_jsqr(ch, 2u, G474_JEXTSEL_TIM1_TRGO2);
  CM4_REG(adc + ADC_ISR) = ADC_ISR_JEOC | ADC_ISR_JEOS;
  CM4_REG(adc + ADC_IER) = irq ? ADC_IER_JEOSIE : 0u;
  /* the set-only bits written as 0 are left as they are (RM0440 ADC_CR) */
  CM4_REG(adc + ADC_CR) = ADC_CR_ADVREGEN | ADC_CR_JADSTART; /* conversions at each TRGO2 */
}

static void adc_init(fw_port_t *port) {
  CM4_REG(RCC + RCC_CCIPR) =
      (CM4_REG(RCC + RCC_CCIPR) & ~(3u << RCC_CCIPR_ADC12SEL_POS)) | (2u << RCC_CCIPR_ADC12SEL_POS);
  CM4_REG(RCC + RCC_AHB2ENR) |= RCC_AHB2ENR_ADC12EN;
  (void)CM4_REG(RCC + RCC_AHB2ENR);
  /* synchronous clock HCLK / 4 = 42.5 MHz (<= 60 MHz); independent ADCs */
  CM4_REG(G4_ADC12_COMMON_BASE + ADCC_CCR) = 3u << ADCC_CCR_CKMODE_POS;
  pin_mode(G474_ADC_IA_PORT, G474_ADC_IA_PIN, PIN_ANALOG, 0u, 0u);
  pin_mode(G474_ADC_IB_PORT, G474_ADC_IB_PIN, PIN_ANALOG, 0u, 0u);
  pin_mode(G474_ADC_IC_PORT, G474_ADC_IC_PIN, PIN_ANALOG, 0u, 0u);
  pin_mode(G474_ADC_UDC_PORT, G474_ADC_UDC_PIN, PIN_ANALOG, 0u, 0u);
  /* rank 1 of both samples at once: i_a (ADC1) with i_b (ADC2); rank 2: i_c, u_dc */
  const uint8_t ch1[2] = {G474_ADC_IA_CH, G474_ADC_IC_CH};
  const uint8_t ch2[2] = {G474_ADC_IB_CH, G474_ADC_UDC_CH};
  adc_enable(ADC2, ch2, false);
  adc_enable(ADC1, ch1, true); /* ADC1's end of sequence is the control interrupt */
  port->adc_max = G474_ADC_OVERSAMPLE == 4u ? 8191u : 4095u;
}

bool g474_adc_irq_ack(fw_port_t *port) {
  if ((CM4_REG(ADC1 + ADC_ISR) & ADC_ISR_JEOS) == 0u) {
    return false;
  }
  CM4_REG(ADC1 + ADC_ISR) = ADC_ISR_JEOS | ADC_ISR_JEOC;
  port->adc_pending = 1u;
  return true;
}

bool fw_port_adc_read(fw_port_t *port, fw_adc_inputs_t *adc) {
  /* ADC2 runs the same sequence timing from the same trigger: done with ADC1 */
  uint32_t spin = 16u;
  while ((CM4_REG(ADC2 + ADC_ISR) & ADC_ISR_JEOS) == 0u && spin-- > 0u) {
  }
  const bool fresh = port->adc_pending != 0u && (CM4_REG(ADC2 + ADC_ISR) & ADC_ISR_JEOS) != 0u;
  CM4_REG(ADC2 + ADC_ISR) = ADC_ISR_JEOS | ADC_ISR_JEOC;
  port->adc_pending = 0u;
  const uint32_t max = port->adc_max;
  adc->i_abc_counts[0] =
      g474_adc_current_counts(CM4_REG(ADC1 + ADC_JDR1), max, G474_CURRENT_INVERT);
  adc->i_abc_counts[1] =
      g474_adc_current_counts(CM4_REG(ADC2 + ADC_JDR1), max, G474_CURRENT_INVERT);
  adc->i_abc_counts[2] =
      g474_adc_current_counts(CM4_REG(ADC1 + ADC_JDR2), max, G474_CURRENT_INVERT);
  adc->u_dc_counts = (uint16_t)(CM4_REG(ADC2 + ADC_JDR2) & 0xFFFFu);
  if (!fresh) {
    port->adc_stale++;
  }
  return fresh;
}

void g474_isr_cycles(fw_port_t *port, uint32_t start) {
  const uint32_t n = g474_cycles() - start;
  port->isr_cycles_last = n;
  if (n > port->isr_cycles_max) {
    port->isr_cycles_max = n;
  }
}

/* ---- reference scale: TIM2 in encoder mode (RM0440 "General-purpose timers
 *      (TIM2/TIM3/TIM4/TIM5)", encoder interface mode) ---- */

static void enc_init(fw_port_t *port) {
  port->ref_referenced = G474_REF_INDEX ? 0u : 1u;
  port->ref_origin = 0u;
#if G474_REF_SCALE
  CM4_REG(RCC + RCC_APB1ENR1) |= RCC_APB1ENR1_TIM2EN;
  (void)CM4_REG(RCC + RCC_APB1ENR1);
  pin_mode(G474_ENC_A_PORT, G474_ENC_A_PIN, PIN_AF, G474_ENC_AF, 1u);
  pin_mode(G474_ENC_B_PORT, G474_ENC_B_PIN, PIN_AF, G474_ENC_AF, 1u);
  CM4_REG(TIM2 + TIM_CR1) = 0u;
  CM4_REG(TIM2 + TIM_PSC) = 0u;
  CM4_REG(TIM2 + TIM_ARR) = 0xFFFFFFFFu; /* 32-bit counter: no extension needed */
  /* IC1 <- TI1, IC2 <- TI2, filter fCK_INT N = 8 (47 ns); IC3 <- TI3 (index);
     IC4 <- TRC = ITR0 = TIM1 TRGO (OC4REF: the ADC trigger) */
  CM4_REG(TIM2 + TIM_CCMR1) = (1u << TIM_CCMR_CCS_POS(0u)) | (3u << TIM_CCMR_ICF_POS(0u)) |
                              (1u << TIM_CCMR_CCS_POS(1u)) | (3u << TIM_CCMR_ICF_POS(1u));
  CM4_REG(TIM2 + TIM_CCMR2) =
      (1u << TIM_CCMR_CCS_POS(0u)) | (3u << TIM_CCMR_ICF_POS(0u)) | (3u << TIM_CCMR_CCS_POS(1u));
  CM4_REG(TIM2 + TIM_CCER) = (G474_ENC_INVERT ? TIM_CCER_CCP(1u) : 0u) |
                             (G474_REF_INDEX ? TIM_CCER_CCE(3u) : 0u) | TIM_CCER_CCE(4u);
  /* encoder mode 3 (x4: both edges of both inputs), trigger ITR0 */
  CM4_REG(TIM2 + TIM_SMCR) = (3u << TIM_SMCR_SMS_POS) | (0u << TIM_SMCR_TS_POS);
  CM4_REG(TIM2 + TIM_EGR) = TIM_EGR_UG;
  CM4_REG(TIM2 + TIM_SR) = 0u;
  CM4_REG(TIM2 + TIM_CR1) = TIM_CR1_CEN;
#if G474_REF_INDEX
  pin_mode(G474_ENC_Z_PORT, G474_ENC_Z_PIN, PIN_AF, G474_ENC_AF, 1u);
#endif
  if (G474_REF_FAULT_PORT != G474_NO_PIN) {
    pin_mode(G474_REF_FAULT_PORT, G474_REF_FAULT_PIN, PIN_IN, 0u,
             G474_REF_FAULT_ACTIVE_LOW ? 1u : 2u);
  }
#endif
}

uint8_t fw_port_ref_read(fw_port_t *port, int32_t *count) {
#if G474_REF_SCALE
  const uint32_t sr = CM4_REG(TIM2 + TIM_SR);
  uint32_t cnt;
  if ((sr & TIM_SR_CC4IF) != 0u) {
    cnt = CM4_REG(TIM2 + TIM_CCR4); /* latched at the ADC trigger; the read clears CC4IF */
  } else {
    cnt = CM4_REG(TIM2 + TIM_CNT);
    port->ref_latch_missed++;
  }
  if (port->ref_referenced == 0u && (sr & TIM_SR_CC3IF) != 0u) {
    port->ref_origin = CM4_REG(TIM2 + TIM_CCR3); /* the count at the reference mark */
    port->ref_referenced = 1u;
    CM4_REG(TIM2 + TIM_CCER) &= ~TIM_CCER_CCE(3u); /* later marks change nothing */
  }
  *count = (int32_t)(cnt - port->ref_origin);
  if (G474_REF_FAULT_PORT != G474_NO_PIN) {
    const uint32_t level =
        (CM4_REG(G4_GPIO_BASE(G474_REF_FAULT_PORT) + GPIO_IDR) >> G474_REF_FAULT_PIN) & 1u;
    if (level == (G474_REF_FAULT_ACTIVE_LOW ? 0u : 1u)) {
      return (uint8_t)FW_REF_FAULT;
    }
  }
  return (uint8_t)(port->ref_referenced != 0u ? FW_REF_OK : FW_REF_NOT_REFERENCED);
#else
  (void)port;
  (void)count;
  return (uint8_t)FW_REF_NONE;
#endif
}

/* ---- FDCAN1 in classic CAN mode (RM0440 "FD controller area network") ---- */

static void can_init(void) {
  g474_can_timing_t bt;
  if (!g474_fdcan_bit_timing(G474_CAN_BITRATE, G474_HSE_HZ, &bt)) {
    board_fatal(G474_FATAL_CONFIG);
  }
  CM4_REG(RCC + RCC_CCIPR) &= ~(3u << RCC_CCIPR_FDCANSEL_POS); /* kernel clock: HSE 24 MHz */
  CM4_REG(RCC + RCC_APB1ENR1) |= RCC_APB1ENR1_FDCANEN;
  (void)CM4_REG(RCC + RCC_APB1ENR1);
  pin_mode(G474_CAN_RX_PORT, G474_CAN_RX_PIN, PIN_AF, G474_CAN_AF, 1u);
  pin_mode(G474_CAN_TX_PORT, G474_CAN_TX_PIN, PIN_AF, G474_CAN_AF, 0u);
  CM4_REG(G4_FDCAN_CFG_BASE) = 0u; /* CKDIV: kernel clock / 1 */
  CM4_REG(CAN + FDCAN_CCCR) |= FDCAN_CCCR_INIT;
  if (!wait_bits(CAN + FDCAN_CCCR, FDCAN_CCCR_INIT, FDCAN_CCCR_INIT, US(1000u))) {
    board_fatal(G474_FATAL_CAN);
  }
  CM4_REG(CAN + FDCAN_CCCR) |= FDCAN_CCCR_CCE;
  /* classic CAN: no FD operation, no bit-rate switching; automatic retransmission */
  CM4_REG(CAN + FDCAN_CCCR) &= ~(FDCAN_CCCR_FDOE | FDCAN_CCCR_BRSE | FDCAN_CCCR_DAR);
  CM4_REG(CAN + FDCAN_NBTP) = bt.nbtp;
  for (uint32_t off = 0u; off < G474_CANRAM_SIZE; off += 4u) {
    CM4_REG(CANRAM + off) = 0u;
  }
  /* one standard filter, id 0 mask 0: every 11-bit frame into RX FIFO 0;
     non-matching and extended frames rejected, remote frames filtered */
  CM4_REG(CANRAM + G474_CANRAM_FLS) = g474_can_std_filter(0u, 0u);
  CM4_REG(CAN + FDCAN_RXGFC) = (1u << FDCAN_RXGFC_LSS_POS) | (2u << FDCAN_RXGFC_ANFS_POS) |
                               (2u << FDCAN_RXGFC_ANFE_POS) | (1u << 0) /* RRFE */;
  CM4_REG(CAN + FDCAN_TXBC) = 0u; /* TX FIFO mode (TFQM = 0) */
  CM4_REG(CAN + FDCAN_IR) = 0xFFFFFFFFu;
  CM4_REG(CAN + FDCAN_IE) = FDCAN_IE_RF0NE;
  CM4_REG(CAN + FDCAN_ILS) = 0u; /* every group on line 0 */
  CM4_REG(CAN + FDCAN_ILE) = FDCAN_ILE_EINT0;
  CM4_REG(CAN + FDCAN_CCCR) &= ~FDCAN_CCCR_INIT;
  if (!wait_bits(CAN + FDCAN_CCCR, FDCAN_CCCR_INIT, 0u, US(10000u))) {
    board_fatal(G474_FATAL_CAN);
  }
}

void g474_can_rx_irq(fw_port_t *port, fw_board_t *board) {
  const uint32_t ir = CM4_REG(CAN + FDCAN_IR);
  CM4_REG(CAN + FDCAN_IR) = ir & (FDCAN_IR_RF0N | FDCAN_IR_RF0L);
  if ((ir & FDCAN_IR_RF0L) != 0u) {
    port->can_rx_lost++;
  }
  for (uint32_t guard = 0u; guard < 3u; guard++) {
    const uint32_t s = CM4_REG(CAN + FDCAN_RXF0S);
    if ((s & FDCAN_RXF0S_F0FL_MASK) == 0u) {
      break;
    }
    const uint32_t gi = (s >> FDCAN_RXF0S_F0GI_POS) & 3u;
    const uint32_t e = CANRAM + G474_CANRAM_RF0 + gi * G474_CANRAM_ELEM;
    const uint32_t r0 = CM4_REG(e), r1 = CM4_REG(e + 4u);
    if ((r0 & (1u << 30)) == 0u && (r1 & (1u << 21)) == 0u) { /* 11-bit, classic */
      fw_can_frame_t f;
      f.id = (uint16_t)((r0 >> 18) & 0x7FFu);
      f.rtr = (uint8_t)((r0 >> 29) & 1u);
      const uint32_t dlc = (r1 >> 16) & 0xFu;
      f.dlc = (uint8_t)(dlc > 8u ? 8u : dlc);
      const uint32_t d0 = CM4_REG(e + 8u), d1 = CM4_REG(e + 12u);
      for (uint32_t i = 0u; i < 4u; i++) {
        f.data[i] = (uint8_t)(d0 >> (8u * i));
        f.data[4u + i] = (uint8_t)(d1 >> (8u * i));
      }
      if (!fw_board_can_rx_isr(board, &f)) {
        port->can_rx_dropped++;
      }
    }
    CM4_REG(CAN + FDCAN_RXF0A) = gi;
  }
}

bool fw_port_can_send(fw_port_t *port, const fw_can_frame_t *frame) {
  if ((CM4_REG(CAN + FDCAN_CCCR) & FDCAN_CCCR_INIT) != 0u) {
    /* bus-off set INIT: clearing it starts the recovery (128 x 11 recessive bits) */
    CM4_REG(CAN + FDCAN_CCCR) &= ~FDCAN_CCCR_INIT;
    port->can_bus_off++;
    return false;
  }
  const uint32_t q = CM4_REG(CAN + FDCAN_TXFQS);
  if ((q & FDCAN_TXFQS_TFQF) != 0u) {
    return false;
  }
  const uint32_t pi = (q >> FDCAN_TXFQS_TFQPI_POS) & 3u;
  const uint32_t e = CANRAM + G474_CANRAM_TXB + pi * G474_CANRAM_ELEM;
  uint32_t d[2] = {0u, 0u};
  for (uint32_t i = 0u; i < 8u && i < frame->dlc; i++) {
    d[i / 4u] |= (uint32_t)frame->data[i] << (8u * (i % 4u));
  }
  CM4_REG(e) = g474_can_word0(frame->id, frame->rtr != 0u);
  CM4_REG(e + 4u) = g474_can_word1(frame->dlc);
  CM4_REG(e + 8u) = d[0];
  CM4_REG(e + 12u) = d[1];
  CM4_REG(CAN + FDCAN_TXBAR) = 1u << pi;
  return true;
}

/* ---- serial link: LPUART1 (ST-LINK virtual COM port) with DMA1 channel 1
 *      through DMAMUX1 channel 0 (RM0440 "LPUART", "DMA", "DMAMUX") ---- */

static void uart_init(fw_port_t *port) {
  const uint32_t brr = g474_lpuart_brr(G474_SYSCLK_HZ, G474_UART_BAUD);
  if (brr == 0u) {
    board_fatal(G474_FATAL_CONFIG);
  }
  byte_ring_init(&port->tx, port->tx_buf, G474_UART_RING);
  port->dma_len = 0u;
  CM4_REG(RCC + RCC_CCIPR) &= ~(3u << RCC_CCIPR_LPUART1SEL_POS); /* PCLK1 */
  CM4_REG(RCC + RCC_APB1ENR2) |= RCC_APB1ENR2_LPUART1EN;
  CM4_REG(RCC + RCC_AHB1ENR) |= RCC_AHB1ENR_DMA1EN | RCC_AHB1ENR_DMAMUX1EN;
  (void)CM4_REG(RCC + RCC_AHB1ENR);
  pin_mode(G474_UART_TX_PORT, G474_UART_TX_PIN, PIN_AF, G474_UART_AF, 0u);
  pin_mode(G474_UART_RX_PORT, G474_UART_RX_PIN, PIN_AF, G474_UART_AF, 1u);
  CM4_REG(UART + USART_CR1) = 0u;
  CM4_REG(UART + USART_BRR) = brr; /* 8N1 */
  CM4_REG(UART + USART_CR3) = USART_CR3_DMAT;
  CM4_REG(UART + USART_CR1) = USART_CR1_TE | USART_CR1_UE;
  CM4_REG(G4_DMAMUX1_BASE + DMAMUX_CCR(0u)) = DMAMUX_REQ_LPUART1_TX; /* DMA1 ch 1 = mux ch 0 */
  CM4_REG(DMA + DMA_CH_CCR(DMA_CH)) = 0u;
  CM4_REG(DMA + DMA_CH_CPAR(DMA_CH)) = UART + USART_TDR;
}

/* start the next contiguous chunk of the ring (UART priority or masked) */
static void uart_kick(fw_port_t *port) {
  if (port->dma_len != 0u) {
    return;
  }
  const uint32_t used = byte_ring_used(&port->tx);
  if (used == 0u) {
    return;
  }
  const uint32_t t = atomic_load_explicit(&port->tx.tail, memory_order_relaxed) & port->tx.mask;
  const uint32_t to_end = port->tx.mask + 1u - t;
  const uint32_t n = used < to_end ? used : to_end;
  port->dma_len = n;
  CM4_REG(DMA + DMA_CH_CMAR(DMA_CH)) = (uint32_t)(uintptr_t)&port->tx_buf[t];
  CM4_REG(DMA + DMA_CH_CNDTR(DMA_CH)) = n;
  const uint32_t ccr =
      DMA_CCR_DIR | DMA_CCR_MINC | DMA_CCR_TCIE | DMA_CCR_TEIE | (1u << DMA_CCR_PL_POS);
  CM4_REG(DMA + DMA_CH_CCR(DMA_CH)) = ccr; /* configured while disabled, then enabled */
  CM4_REG(DMA + DMA_CH_CCR(DMA_CH)) = ccr | DMA_CCR_EN;
}

void g474_uart_dma_irq(fw_port_t *port) {
  const uint32_t isr = CM4_REG(DMA + DMA_ISR);
  if ((isr & (DMA_ISR_TCIF(DMA_CH) | DMA_ISR_TEIF(DMA_CH))) == 0u) {
    return;
  }
  CM4_REG(DMA + DMA_IFCR) = DMA_IFCR_CGIF(DMA_CH);
  CM4_REG(DMA + DMA_CH_CCR(DMA_CH)) = 0u;
  if ((isr & DMA_ISR_TEIF(DMA_CH)) != 0u) {
    port->dma_errors++;
  }
  const uint32_t t = atomic_load_explicit(&port->tx.tail, memory_order_relaxed);
  atomic_store_explicit(&port->tx.tail, t + port->dma_len, memory_order_release);
  port->dma_len = 0u;
  uart_kick(port);
}

size_t fw_port_uart_write(fw_port_t *port, const uint8_t *data, size_t len) {
  const size_t n = byte_ring_write(&port->tx, data, len);
  if (n > 0u) {
    const uint32_t key = cm4_basepri_get();
    cm4_basepri_max(CM4_PRIO(G474_PRIO_UART));
    uart_kick(port);
    cm4_basepri_set(key);
  }
  return n;
}

/* ---- critical sections: BASEPRI at the control interrupt's level ---- */

uint32_t fw_port_critical_enter(fw_port_t *port) {
  (void)port;
  return cm4_critical_enter(G474_PRIO_CONTROL); /* masks levels 1..15; the break (0) stays */
}

void fw_port_critical_exit(fw_port_t *port, uint32_t key) {
  (void)port;
  cm4_critical_exit(key);
}

void fw_port_info(fw_port_t *port, fw_port_info_t *info) {
  (void)port;
  info->kind = (uint8_t)FW_DRIVE_HARDWARE;
  info->board = "nucleo_g474re";
}

/* ---- parameter page: one flash page (RM0440 "Embedded flash memory":
 *      program/erase, ECC) through _common/nvm_page.c ---- */

static void flash_unlock(void) {
  if ((CM4_REG(FLASHR + FLASH_CR) & FLASH_CR_LOCK) != 0u) {
    CM4_REG(FLASHR + FLASH_KEYR) = FLASH_KEY1;
    CM4_REG(FLASHR + FLASH_KEYR) = FLASH_KEY2;
  }
}

static void flash_lock(void) {
  CM4_REG(FLASHR + FLASH_CR) |= FLASH_CR_LOCK;
}

/* wait for the end of an operation, kicking the watchdog (an erase takes up to
   about 40 ms); false on an error flag or a timeout */
static bool flash_wait(fw_port_t *port, uint32_t us) {
  const uint32_t t0 = g474_cycles();
  const uint32_t limit = US(us);
  while ((CM4_REG(FLASHR + FLASH_SR) & FLASH_SR_BSY) != 0u) {
    g474_iwdg_kick();
    if (g474_cycles() - t0 > limit) {
      port->flash_errors++;
      return false;
    }
  }
  const uint32_t err = CM4_REG(FLASHR + FLASH_SR) & FLASH_SR_ERRORS;
  CM4_REG(FLASHR + FLASH_SR) = err | FLASH_SR_EOP; /* write 1 to clear */
  if (err != 0u) {
    port->flash_errors++;
    return false;
  }
  return true;
}

/* the flash's data cache may hold the page's old words */
static void flash_cache_flush(void) {
  const uint32_t acr = CM4_REG(FLASHR + FLASH_ACR);
  CM4_REG(FLASHR + FLASH_ACR) = acr & ~FLASH_ACR_DCEN;
  CM4_REG(FLASHR + FLASH_ACR) = (acr & ~FLASH_ACR_DCEN) | FLASH_ACR_DCRST;
  CM4_REG(FLASHR + FLASH_ACR) = acr;
}

static bool nvm_erase(void *ctx) {
  fw_port_t *port = (fw_port_t *)ctx;
  flash_unlock();
  bool ok = flash_wait(port, 1000u);
  if (ok) {
    CM4_REG(FLASHR + FLASH_CR) = FLASH_CR_PER | (port->geom.page << FLASH_CR_PNB_POS) |
                                 (port->geom.bank2 ? FLASH_CR_BKER : 0u);
    CM4_REG(FLASHR + FLASH_CR) |= FLASH_CR_STRT;
    ok = flash_wait(port, 100000u);
  }
  CM4_REG(FLASHR + FLASH_CR) = 0u;
  flash_lock();
  flash_cache_flush();
  atomic_store_explicit(&port->nvm_ecc_bad, 0u, memory_order_relaxed);
  return ok;
}

static bool nvm_program(void *ctx, uint32_t offset, const uint8_t *data, uint32_t len) {
  fw_port_t *port = (fw_port_t *)ctx;
  if (offset % 8u != 0u || len % 8u != 0u || offset + len > port->geom.size) {
    return false;
  }
  flash_unlock();
  bool ok = flash_wait(port, 1000u);
  for (uint32_t i = 0u; ok && i < len; i += 8u) {
    uint32_t w[2];
    memcpy(w, data + i, 8u);
    const uint32_t a = port->geom.addr + offset + i;
    CM4_REG(FLASHR + FLASH_CR) = FLASH_CR_PG; /* one double word: both words, in order */
    CM4_REG(a) = w[0];
    CM4_REG(a + 4u) = w[1];
    ok = flash_wait(port, 1000u);
  }
  CM4_REG(FLASHR + FLASH_CR) = 0u;
  flash_lock();
  flash_cache_flush();
  return ok;
}

/* Read every double word of the page once: a double ECC error (a double word
 * torn in its program operation) raises the NMI, whose handler (g474_nmi)
 * marks the page; such a page reads as g474_nvm_bad_page, which the drive
 * rejects by its CRC and boots on its defaults. */
static const uint8_t *nvm_view(void *ctx) {
  fw_port_t *port = (fw_port_t *)ctx;
  uint32_t sum = 0u;
  for (uint32_t off = 0u; off < port->geom.size; off += 4u) {
    sum ^= CM4_REG(port->geom.addr + off);
  }
  (void)sum;
  __asm volatile("dsb\n isb" ::: "memory");
  if (atomic_load_explicit(&port->nvm_ecc_bad, memory_order_relaxed) != 0u) {
    return g474_nvm_bad_page;
  }
  return (const uint8_t *)(uintptr_t)port->geom.addr;
}

static void nvm_init(fw_port_t *port) {
  const uint32_t kb = *(const volatile uint16_t *)(uintptr_t)G4_FLASHSIZE_REG;
  port->flash_kb = kb;
  port->dual_bank = (CM4_REG(FLASHR + FLASH_OPTR) & FLASH_OPTR_DBANK) != 0u ? 1u : 0u;
  if (!g474_nvm_geometry(kb, port->dual_bank != 0u, &port->geom) ||
      port->geom.size > G474_NVM_BAD_PAGE_SIZE) {
    memset(&port->geom, 0, sizeof port->geom);
  }
  atomic_store_explicit(&port->nvm_ecc_bad, 0u, memory_order_relaxed);
  port->nvm.ctx = port;
  port->nvm.page_size = port->geom.size;
  port->nvm.prog_unit = 8u; /* double-word programming */
  port->nvm.erase = nvm_erase;
  port->nvm.program = nvm_program;
  port->nvm.view = nvm_view;
}

fw_nvm_status_t fw_port_nvm_read(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len) {
  if (port->geom.size == 0u) {
    if (len != NULL) {
      *len = 0u;
    }
    return FW_NVM_UNSUPPORTED;
  }
  return nvm_page_read(&port->nvm, buf, cap, len);
}

fw_nvm_status_t fw_port_nvm_write(fw_port_t *port, const uint8_t *data, size_t len) {
  if (port->geom.size == 0u) {
    return FW_NVM_UNSUPPORTED;
  }
  return nvm_page_write(&port->nvm, data, len);
}

void g474_nmi(fw_port_t *port) {
  const uint32_t eccr = CM4_REG(FLASHR + FLASH_ECCR);
  if ((eccr & (G474_ECCR_ECCD | G474_ECCR_ECCD2)) != 0u) {
    CM4_REG(FLASHR + FLASH_ECCR) = eccr; /* write 1 to clear the flags, keep ECCCIE */
    if (port != NULL && port->geom.size != 0u &&
        g474_flash_ecc_in_page(eccr, port->flash_kb, port->dual_bank != 0u, &port->geom)) {
      atomic_store_explicit(&port->nvm_ecc_bad, 1u, memory_order_relaxed);
      port->ecc_events++;
      return; /* the read completes; nvm_view reports the page bad */
    }
    board_fatal(G474_FATAL_ECC); /* in the code or constants: nothing can be trusted */
  }
  if ((CM4_REG(RCC + RCC_CIFR) & RCC_CIFR_CSSF) != 0u) {
    CM4_REG(RCC + RCC_CICR) = RCC_CIFR_CSSF;
    board_fatal(G474_FATAL_CSS);
  }
  board_fatal(G474_FATAL_NMI);
}

/* ---- watchdog (RM0440 "Independent watchdog (IWDG)") ---- */

static void iwdg_start(void) {
  uint32_t pr = 0u, rl = 0u;
  if (!g474_iwdg_config(G474_IWDG_TIMEOUT_MS, G474_LSI_HZ, &pr, &rl)) {
    board_fatal(G474_FATAL_CONFIG);
  }
  CM4_REG(G4_DBGMCU_BASE + DBGMCU_APB1FZR1) |= DBGMCU_APB1FZR1_IWDG; /* stopped when halted */
  CM4_REG(G4_IWDG_BASE + IWDG_KR) = IWDG_KEY_START;                  /* starts the LSI too */
  CM4_REG(G4_IWDG_BASE + IWDG_KR) = IWDG_KEY_UNLOCK;
  CM4_REG(G4_IWDG_BASE + IWDG_PR) = pr;
  CM4_REG(G4_IWDG_BASE + IWDG_RLR) = rl;
  (void)wait_bits(G4_IWDG_BASE + IWDG_SR, 7u, 0u, US(50000u));
  CM4_REG(G4_IWDG_BASE + IWDG_KR) = IWDG_KEY_RELOAD;
}

void g474_iwdg_kick(void) {
  CM4_REG(G4_IWDG_BASE + IWDG_KR) = IWDG_KEY_RELOAD;
}

/* ---- bring-up ---- */

void g474_port_init(fw_port_t *port) {
  memset(port, 0, sizeof *port);
  atomic_store_explicit(&port->brk_latched, 0u, memory_order_relaxed);
  CM4_REG(RCC + RCC_APB2ENR) |= RCC_APB2ENR_SYSCFGEN;
  pwm_init(port, 24000u);
  adc_init(port);
  enc_init(port);
  can_init();
  uart_init(port);
  nvm_init(port);
}

void g474_port_start(fw_port_t *port) {
  cm4_irq_priority(G4_IRQ_TIM1_BRK, CM4_PRIO(G474_PRIO_BREAK));
  cm4_irq_priority(G4_IRQ_ADC1_2, CM4_PRIO(G474_PRIO_CONTROL));
  cm4_pendsv_priority(CM4_PRIO(G474_PRIO_SUPERVISION));
  cm4_irq_priority(G4_IRQ_FDCAN1_IT0, CM4_PRIO(G474_PRIO_CAN));
  cm4_irq_priority(G4_IRQ_DMA1_CH1, CM4_PRIO(G474_PRIO_UART));
  pwm_start(); /* outputs still off (MOE = 0): the core enables them */
  CM4_REG(ADC1 + ADC_ISR) = ADC_ISR_JEOS | ADC_ISR_JEOC;
  CM4_REG(ADC2 + ADC_ISR) = ADC_ISR_JEOS | ADC_ISR_JEOC;
  port->adc_pending = 0u;
  cm4_irq_unpend(G4_IRQ_ADC1_2);
  cm4_irq_enable(G4_IRQ_TIM1_BRK);
  cm4_irq_enable(G4_IRQ_ADC1_2);
  cm4_irq_enable(G4_IRQ_FDCAN1_IT0);
  cm4_irq_enable(G4_IRQ_DMA1_CH1);
  iwdg_start();
}
