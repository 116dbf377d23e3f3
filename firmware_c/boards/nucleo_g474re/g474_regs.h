/**
 * @file g474_regs.h
 * @brief STM32G474 peripheral registers the port uses, written from the
 *        reference manual RM0440 (rev. 8): base addresses from section 2.2.2
 *        (memory map), offsets and bit positions from each peripheral's
 *        register map (the section is named at each block). No vendor header.
 *
 * Only what the port touches is here. Bit positions that host tests check
 * (tests/c/test_g474_calc.c decodes register values with its own constants)
 * are used through g474_calc.c; the rest is exercised on silicon only.
 */
#ifndef PMLSM_G474_REGS_H
#define PMLSM_G474_REGS_H

#include <stdint.h>

#define G4_REG(base, off) (*(volatile uint32_t *)(uintptr_t)((base) + (off)))

/* ---- memory map (RM0440 "Memory map and register boundary addresses") ---- */
#define G4_FLASH_BASE 0x08000000u
#define G4_FLASHSIZE_REG                                                                           \
  0x1FFF75E0u /**< flash size in KB (RM0440 "Device electronic signature", flash size data         \
                 register) */
#define G4_SRAM1_BASE 0x20000000u
#define G4_CCMSRAM_BASE 0x10000000u
#define G4_TIM2_BASE 0x40000000u
#define G4_TIM3_BASE 0x40000400u
#define G4_TIM4_BASE 0x40000800u
#define G4_IWDG_BASE 0x40003000u
#define G4_FDCAN1_BASE 0x40006400u
#define G4_FDCAN_CFG_BASE 0x40006500u /**< FDCAN_CKDIV */
#define G4_PWR_BASE 0x40007000u
#define G4_LPUART1_BASE 0x40008000u
#define G4_SRAMCAN_BASE 0x4000A400u /**< FDCAN message RAM */
#define G4_SYSCFG_BASE 0x40010000u
#define G4_TIM1_BASE 0x40012C00u
#define G4_DMA1_BASE 0x40020000u
#define G4_DMAMUX1_BASE 0x40020800u
#define G4_RCC_BASE 0x40021000u
#define G4_FLASHR_BASE 0x40022000u
#define G4_GPIO_BASE(port) (0x48000000u + 0x400u * (uint32_t)(port))
#define G4_ADC1_BASE 0x50000000u
#define G4_ADC2_BASE 0x50000100u
#define G4_ADC12_COMMON_BASE 0x50000300u
#define G4_DBGMCU_BASE 0xE0042000u

/* ---- RCC (RM0440 "RCC registers") ---- */
#define RCC_CR 0x00u
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_CSSON (1u << 19)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_CFGR 0x08u
#define RCC_CFGR_SW_POS 0u   /* 2 bits: 11 = PLL */
#define RCC_CFGR_SWS_POS 2u  /* 2 bits */
#define RCC_CFGR_HPRE_POS 4u /* 4 bits: 0xxx /1, 1000 /2 */
#define RCC_CFGR_PPRE1_POS 8u
#define RCC_CFGR_PPRE2_POS 11u
#define RCC_PLLCFGR 0x0Cu /* layout: g474_calc.h */
#define RCC_CIFR 0x1Cu
#define RCC_CIFR_CSSF (1u << 8)
#define RCC_CICR 0x20u
#define RCC_AHB1ENR 0x48u
#define RCC_AHB1ENR_DMA1EN (1u << 0)
#define RCC_AHB1ENR_DMAMUX1EN (1u << 2)
#define RCC_AHB2ENR 0x4Cu
#define RCC_AHB2ENR_GPIOEN(port) (1u << (port))
#define RCC_AHB2ENR_ADC12EN (1u << 13)
#define RCC_APB1ENR1 0x58u
#define RCC_APB1ENR1_TIM2EN (1u << 0)
#define RCC_APB1ENR1_FDCANEN (1u << 25)
#define RCC_APB1ENR1_PWREN (1u << 28)
#define RCC_APB1ENR2 0x5Cu
#define RCC_APB1ENR2_LPUART1EN (1u << 0)
#define RCC_APB2ENR 0x60u
#define RCC_APB2ENR_SYSCFGEN (1u << 0)
#define RCC_APB2ENR_TIM1EN (1u << 11)
#define RCC_CCIPR 0x88u
#define RCC_CCIPR_LPUART1SEL_POS 10u /* 00 PCLK1 */
#define RCC_CCIPR_FDCANSEL_POS 24u   /* 00 HSE, 01 PLL Q, 10 PCLK1 */
#define RCC_CCIPR_ADC12SEL_POS 28u   /* 00 none, 01 PLL P, 10 SYSCLK */
#define RCC_CSR 0x94u
#define RCC_CSR_LSION (1u << 0)
#define RCC_CSR_LSIRDY (1u << 1)

/* ---- PWR (RM0440 "PWR registers") ---- */
#define PWR_CR1 0x00u
#define PWR_CR1_VOS_POS 9u /* 2 bits: 01 range 1 */
#define PWR_SR2 0x14u
#define PWR_SR2_VOSF (1u << 10)
#define PWR_CR5 0x80u
#define PWR_CR5_R1MODE (1u << 8) /* 0: range 1 boost mode */

/* ---- FLASH (RM0440 "FLASH registers") ---- */
#define FLASH_ACR 0x00u
#define FLASH_ACR_LATENCY_POS 0u /* 4 bits */
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)
#define FLASH_ACR_ICRST (1u << 11)
#define FLASH_ACR_DCRST (1u << 12)
#define FLASH_KEYR 0x08u
#define FLASH_KEY1 0x45670123u
#define FLASH_KEY2 0xCDEF89ABu
#define FLASH_SR 0x10u
#define FLASH_SR_EOP (1u << 0)
#define FLASH_SR_OPERR (1u << 1)
#define FLASH_SR_PROGERR (1u << 3)
#define FLASH_SR_WRPERR (1u << 4)
#define FLASH_SR_PGAERR (1u << 5)
#define FLASH_SR_SIZERR (1u << 6)
#define FLASH_SR_PGSERR (1u << 7)
#define FLASH_SR_MISERR (1u << 8)
#define FLASH_SR_FASTERR (1u << 9)
#define FLASH_SR_RDERR (1u << 14)
#define FLASH_SR_OPTVERR (1u << 15)
#define FLASH_SR_BSY (1u << 16)
#define FLASH_SR_ERRORS                                                                            \
  (FLASH_SR_OPERR | FLASH_SR_PROGERR | FLASH_SR_WRPERR | FLASH_SR_PGAERR | FLASH_SR_SIZERR |       \
   FLASH_SR_PGSERR | FLASH_SR_MISERR | FLASH_SR_FASTERR | FLASH_SR_RDERR | FLASH_SR_OPTVERR)
#define FLASH_CR 0x14u
#define FLASH_CR_PG (1u << 0)
#define FLASH_CR_PER (1u << 1)
#define FLASH_CR_PNB_POS 3u /* 7 bits */
#define FLASH_CR_BKER (1u << 11)
#define FLASH_CR_STRT (1u << 16)
#define FLASH_CR_LOCK (1u << 31)
#define FLASH_ECCR 0x18u /* layout: g474_calc.h */
#define FLASH_OPTR 0x20u
#define FLASH_OPTR_DBANK (1u << 22)

/* ---- GPIO (RM0440 "GPIO registers") ---- */
#define GPIO_MODER 0x00u /* 2 bits per pin: 00 in, 01 out, 10 AF, 11 analog */
#define GPIO_OSPEEDR 0x08u
#define GPIO_PUPDR 0x0Cu /* 01 pull-up, 10 pull-down */
#define GPIO_IDR 0x10u
#define GPIO_AFRL 0x20u
#define GPIO_AFRH 0x24u

/* ---- advanced-control timer TIM1 and general-purpose TIM2 (RM0440 "TIM1/TIM8/TIM20 registers",
 * "TIM2/TIM3/TIM4/TIM5 registers") ---- */
#define TIM_CR1 0x00u
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_URS (1u << 2)
#define TIM_CR1_DIR (1u << 4)
#define TIM_CR1_CMS_POS 5u /* 01: centre-aligned mode 1 */
#define TIM_CR1_ARPE (1u << 7)
#define TIM_CR2 0x04u
#define TIM_CR2_MMS_POS 4u /* bits 6:4 (bit 25 is MMS[3]) */
#define TIM_CR2_OIS1 (1u << 8)
#define TIM_CR2_OIS1N (1u << 9)
#define TIM_CR2_MMS2_POS 20u /* 4 bits: 0111 OC4REF */
#define TIM_SMCR 0x08u
#define TIM_SMCR_SMS_POS 0u /* bits 2:0 (bit 16 is SMS[3]): 011 encoder x4 */
#define TIM_SMCR_TS_POS 4u  /* bits 6:4 (bits 21:20 are TS[4:3]): 000 ITR0 */
#define TIM_DIER 0x0Cu
#define TIM_DIER_BIE (1u << 7)
#define TIM_SR 0x10u
#define TIM_SR_UIF (1u << 0)
#define TIM_SR_CC3IF (1u << 3)
#define TIM_SR_CC4IF (1u << 4)
#define TIM_SR_BIF (1u << 7)
#define TIM_EGR 0x14u
#define TIM_EGR_UG (1u << 0)
#define TIM_CCMR1 0x18u
#define TIM_CCMR2 0x1Cu
#define TIM_CCMR_OCPE(ch_in_reg) (1u << (3u + 8u * (ch_in_reg)))
#define TIM_CCMR_OCM_PWM1(ch_in_reg) (6u << (4u + 8u * (ch_in_reg))) /* OCxM = 0110 */
#define TIM_CCMR_OCM_PWM2(ch_in_reg) (7u << (4u + 8u * (ch_in_reg))) /* OCxM = 0111 */
#define TIM_CCMR_CCS_POS(ch_in_reg) (8u * (ch_in_reg))               /* 01 TIx, 11 TRC */
#define TIM_CCMR_ICF_POS(ch_in_reg) (4u + 8u * (ch_in_reg))
#define TIM_CCER 0x20u
#define TIM_CCER_CCE(ch) (1u << (4u * ((ch) - 1u)))
#define TIM_CCER_CCP(ch) (2u << (4u * ((ch) - 1u)))
#define TIM_CCER_CCNE(ch) (4u << (4u * ((ch) - 1u)))
#define TIM_CCER_CCNP(ch) (8u << (4u * ((ch) - 1u)))
#define TIM_CNT 0x24u
#define TIM_PSC 0x28u
#define TIM_ARR 0x2Cu
#define TIM_RCR 0x30u
#define TIM_CCR1 0x34u
#define TIM_CCR2 0x38u
#define TIM_CCR3 0x3Cu
#define TIM_CCR4 0x40u
#define TIM_BDTR 0x44u
#define TIM_BDTR_DTG_POS 0u /* 8 bits, g474_dead_time_dtg */
#define TIM_BDTR_LOCK_POS 8u
#define TIM_BDTR_OSSI (1u << 10)
#define TIM_BDTR_OSSR (1u << 11)
#define TIM_BDTR_BKE (1u << 12)
#define TIM_BDTR_BKP (1u << 13)
#define TIM_BDTR_AOE (1u << 14)
#define TIM_BDTR_MOE (1u << 15)
#define TIM_BDTR_BKF_POS 16u
#define TIM_AF1 0x60u
#define TIM_AF1_BKINE (1u << 0)
#define TIM_AF1_BKINP (1u << 9)

/* ---- ADC (RM0440 "ADC registers") ---- */
#define ADC_ISR 0x00u
#define ADC_ISR_ADRDY (1u << 0)
#define ADC_ISR_JEOC (1u << 5)
#define ADC_ISR_JEOS (1u << 6)
#define ADC_IER 0x04u
#define ADC_IER_JEOSIE (1u << 6)
#define ADC_CR 0x08u
#define ADC_CR_ADEN (1u << 0)
#define ADC_CR_JADSTART (1u << 3)
#define ADC_CR_ADVREGEN (1u << 28)
#define ADC_CR_DEEPPWD (1u << 29)
#define ADC_CR_ADCALDIF (1u << 30)
#define ADC_CR_ADCAL (1u << 31)
#define ADC_CFGR 0x0Cu
#define ADC_CFGR_JQDIS (1u << 31)
#define ADC_CFGR2 0x10u
#define ADC_CFGR2_JOVSE (1u << 1)
#define ADC_CFGR2_OVSR_POS 2u /* 3 bits: ratio 2^(OVSR+1) */
#define ADC_CFGR2_OVSS_POS 5u /* 4 bits: right shift */
#define ADC_SMPR1 0x14u       /* channels 0..9, 3 bits each */
#define ADC_SMPR2 0x18u       /* channels 10..18 */
#define ADC_JSQR 0x4Cu        /* layout: g474_calc.h */
#define ADC_JDR1 0x80u
#define ADC_JDR2 0x84u
#define ADC_DIFSEL 0xB0u
#define ADCC_CCR 0x08u          /* ADC12 common control (offset from the common block) */
#define ADCC_CCR_CKMODE_POS 16u /* 11: HCLK/4, synchronous */

/* ---- FDCAN (RM0440 "FDCAN registers") ---- */
#define FDCAN_CCCR 0x018u
#define FDCAN_CCCR_INIT (1u << 0)
#define FDCAN_CCCR_CCE (1u << 1)
#define FDCAN_CCCR_DAR (1u << 6)
#define FDCAN_CCCR_FDOE (1u << 8)
#define FDCAN_CCCR_BRSE (1u << 9)
#define FDCAN_CCCR_PXHD (1u << 12)
#define FDCAN_NBTP 0x01Cu /* layout: g474_calc.h */
#define FDCAN_IR 0x050u
#define FDCAN_IR_RF0N (1u << 0)
#define FDCAN_IR_RF0L (1u << 2)
#define FDCAN_IR_BO (1u << 19)
#define FDCAN_IE 0x054u
#define FDCAN_IE_RF0NE (1u << 0)
#define FDCAN_ILS 0x058u
#define FDCAN_ILE 0x05Cu
#define FDCAN_ILE_EINT0 (1u << 0)
#define FDCAN_RXGFC 0x080u
#define FDCAN_RXGFC_ANFS_POS 4u /* 2 bits: 10 reject non-matching standard */
#define FDCAN_RXGFC_ANFE_POS 2u /* 2 bits: 10 reject non-matching extended */
#define FDCAN_RXGFC_LSS_POS 16u /* 5 bits: standard filter elements */
#define FDCAN_RXF0S 0x090u
#define FDCAN_RXF0S_F0FL_MASK 0xFu
#define FDCAN_RXF0S_F0GI_POS 8u
#define FDCAN_RXF0A 0x094u
#define FDCAN_TXBC 0x0C0u
#define FDCAN_TXBC_TFQM (1u << 24)
#define FDCAN_TXFQS 0x0C4u
#define FDCAN_TXFQS_TFQPI_POS 16u
#define FDCAN_TXFQS_TFQF (1u << 21)
#define FDCAN_TXBAR 0x0CCu

/* ---- LPUART1 (RM0440 "LPUART registers") ---- */
#define USART_CR1 0x00u
#define USART_CR1_UE (1u << 0)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_FIFOEN (1u << 29)
#define USART_CR3 0x08u
#define USART_CR3_DMAT (1u << 7)
#define USART_BRR 0x0Cu
#define USART_TDR 0x28u
#define USART_ICR 0x20u

/* ---- DMA1 channel 1 and DMAMUX1 channel 0 (RM0440 "DMA registers", "DMAMUX registers") ---- */
#define DMA_ISR 0x00u
#define DMA_IFCR 0x04u
#define DMA_CH_CCR(ch) (0x08u + 0x14u * ((ch) - 1u))
#define DMA_CH_CNDTR(ch) (0x0Cu + 0x14u * ((ch) - 1u))
#define DMA_CH_CPAR(ch) (0x10u + 0x14u * ((ch) - 1u))
#define DMA_CH_CMAR(ch) (0x14u + 0x14u * ((ch) - 1u))
#define DMA_CCR_EN (1u << 0)
#define DMA_CCR_TCIE (1u << 1)
#define DMA_CCR_TEIE (1u << 3)
#define DMA_CCR_DIR (1u << 4) /* read from memory */
#define DMA_CCR_MINC (1u << 7)
#define DMA_CCR_PL_POS 12u
#define DMA_ISR_TCIF(ch) (2u << (4u * ((ch) - 1u)))
#define DMA_ISR_TEIF(ch) (8u << (4u * ((ch) - 1u)))
#define DMA_IFCR_CGIF(ch) (1u << (4u * ((ch) - 1u)))
#define DMAMUX_CCR(mux_ch) (0x04u * (mux_ch))
#define DMAMUX_REQ_LPUART1_TX 35u /* RM0440 "DMAMUX: mapping", request 35 */

/* ---- IWDG (RM0440 "IWDG registers") ---- */
#define IWDG_KR 0x00u
#define IWDG_PR 0x04u
#define IWDG_RLR 0x08u
#define IWDG_SR 0x0Cu
#define IWDG_KEY_START 0xCCCCu
#define IWDG_KEY_UNLOCK 0x5555u
#define IWDG_KEY_RELOAD 0xAAAAu

/* ---- DBGMCU (RM0440 "DBGMCU APB1 freeze register 1", "APB2 freeze") ---- */
#define DBGMCU_APB1FZR1 0x08u
#define DBGMCU_APB1FZR1_IWDG (1u << 12)
#define DBGMCU_APB2FZ 0x10u
#define DBGMCU_APB2FZ_TIM1 (1u << 11)

/* ---- interrupt numbers (RM0440 "Interrupt and exception vectors") ---- */
#define G4_IRQ_FLASH 4u
#define G4_IRQ_DMA1_CH1 11u
#define G4_IRQ_ADC1_2 18u
#define G4_IRQ_FDCAN1_IT0 21u
#define G4_IRQ_FDCAN1_IT1 22u
#define G4_IRQ_TIM1_BRK 24u
#define G4_IRQ_TIM1_UP 25u
#define G4_IRQ_COUNT 102u /* IRQ 0..101: 118 vectors with the 16 of the core */

/* ---- Cortex-M debug (ARMv7-M ARM, "Debug Halting Control and Status Register") ---- */
#define CM4_DHCSR 0xE000EDF0u
#define CM4_DHCSR_C_DEBUGEN (1u << 0)

#endif /* PMLSM_G474_REGS_H */
