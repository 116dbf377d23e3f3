/**
 * @file g474_calc.h
 * @brief Every number the NUCLEO-G474RE port writes into a register, as pure
 *        functions of the clock and the request: they compile on the host and
 *        tests/c/test_g474_calc.c checks them against the reference manual's
 *        formulas (RM0440), computed there independently, with its own copies
 *        of the field positions. No register access here.
 */
#ifndef PMLSM_G474_CALC_H
#define PMLSM_G474_CALC_H

#include <stdbool.h>
#include <stdint.h>

#include "pmlsm/fw_ctrl.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- clocks (RM0440 "Reset and clock control": PLL, clock tree) ---- */

/** The main PLL from the HSE and the resulting clocks. */
typedef struct {
  uint32_t f_in_Hz;  /**< PLL source (HSE) */
  uint32_t pll_m;    /**< input divider 1..16 */
  uint32_t pll_n;    /**< VCO multiplier 8..127 */
  uint32_t pll_r;    /**< SYSCLK divider 2, 4, 6, 8 */
  uint32_t f_vco_Hz; /**< f_in / M * N, 96..344 MHz */
  uint32_t f_sys_Hz; /**< f_vco / R = HCLK = PCLK1 = PCLK2 (prescalers 1) */
  uint32_t flash_ws; /**< flash wait states for f_sys in the chosen range */
  bool boost;        /**< range 1 boost mode (PWR_CR5.R1MODE = 0): f_sys > 150 MHz */
  uint32_t pllcfgr;  /**< RCC_PLLCFGR value: HSE source, M, N, R, PLLREN */
} g474_clock_plan_t;

/** PLLCFGR fields (RM0440 "RCC PLL configuration register"). */
#define G474_PLLCFGR_SRC_HSE 3u /* bits 1:0 */
#define G474_PLLCFGR_M_POS 4u   /* bits 7:4, M - 1 */
#define G474_PLLCFGR_N_POS 8u   /* bits 14:8, N */
#define G474_PLLCFGR_REN (1u << 24)
#define G474_PLLCFGR_R_POS 25u /* bits 26:25, R / 2 - 1 */

/** Plan SYSCLK f_sys_Hz from f_hse_Hz: the first M (smallest) for which an
 *  integer N and R give it exactly within the PLL's ranges (input 2.66..16 MHz,
 *  VCO 96..344 MHz, output <= 170 MHz). False when none does. */
bool g474_clock_plan(uint32_t f_hse_Hz, uint32_t f_sys_Hz, g474_clock_plan_t *plan);

/** Flash wait states for an HCLK (RM0440 "Read access latency", table of
 *  wait states: range 1 boost 34/68/102/136/170 MHz, range 1 normal
 *  30/60/90/120/150 MHz). 0xFFFFFFFF above the range's maximum. */
uint32_t g474_flash_latency(uint32_t hclk_Hz, bool boost);

/* ---- PWM: TIM1 centre-aligned (RM0440 "Advanced-control timers") ---- */

/** ARR for a centre-aligned PWM of f_pwm_Hz on a timer clock f_tim_Hz: the
 *  counter runs 0 -> ARR -> 0, 2 ARR ticks a period; rounded to nearest. */
uint32_t g474_pwm_arr(uint32_t f_tim_Hz, uint32_t f_pwm_Hz);

/** The PWM frequency an ARR gives (Hz). */
float g474_pwm_freq_Hz(uint32_t f_tim_Hz, uint32_t arr);

/** Compare value for a duty 0..1 in PWM mode 1, centre-aligned: the output is
 *  active while CNT < CCR, 2 CCR of the 2 ARR ticks, so CCR = duty x ARR,
 *  rounded, clamped to [0, ARR]; NaN gives ARR / 2. */
static inline uint32_t g474_pwm_compare(float duty, uint32_t arr) {
  if (duty != duty) {
    return arr / 2u;
  }
  if (duty <= 0.0f) {
    return 0u;
  }
  if (duty >= 1.0f) {
    return arr;
  }
  return (uint32_t)(duty * (float)arr + 0.5f);
}

/** BDTR.DTG for a dead time of at least dead_ns at f_dts_Hz (RM0440,
 *  "TIMx break and dead-time register", DTG[7:0]: four ranges of step 1, 2,
 *  8 and 16 tDTS). The smallest encoding giving dead_ns or more; 0xFF (the
 *  largest) when none does. *got_ns (optional): the dead time it gives. */
uint8_t g474_dead_time_dtg(uint32_t dead_ns, uint32_t f_dts_Hz, float *got_ns);

/* ---- ADC sampling instant (RM0440 "Analog-to-digital converters") ---- */

/** The two injected ranks of ADC1 and ADC2, triggered together. */
typedef struct {
  uint32_t f_tim_Hz;   /**< TIM1 clock = HCLK */
  uint32_t adc_div;    /**< ADC clock = HCLK / adc_div (synchronous mode: 4) */
  uint32_t smp_x2;     /**< sampling time x 2 in ADC cycles (6.5 -> 13) */
  uint32_t conv_x2;    /**< conversion x 2 (12 bit: 12.5 -> 25) */
  uint32_t latency_x2; /**< trigger to start of sampling x 2 (ADC cycles) */
  uint32_t oversample; /**< conversions per rank (1 or 4) */
} g474_adc_timing_t;

/** Timer ticks from the trigger to the middle of the current samples: from
 *  the start of rank 1's first sampling phase to the end of rank 2's last
 *  (the phase currents are ranks 1 and 2), halved. TIM1 CCR4 = ARR minus
 *  this puts that middle on the counter's peak, the centre of the low-side
 *  conduction where the shunts carry the phase currents. */
uint32_t g474_adc_trigger_ticks(const g474_adc_timing_t *t);

/** Span of the current samples in timer ticks (first sampling start to last
 *  sampling end). */
uint32_t g474_adc_span_ticks(const g474_adc_timing_t *t);

/** Largest duty at which the current samples, centred on the peak, stay in
 *  every phase's low-side conduction: 1 - span / (2 ARR). */
float g474_adc_max_duty(const g474_adc_timing_t *t, uint32_t arr);

/** ADC_JSQR (RM0440 "ADC injected sequence register"): n ranks (1..4) of
 *  channels ch[], trigger JEXTSEL, rising edge. */
#define G474_JSQR_JL_POS 0u
#define G474_JSQR_JEXTSEL_POS 2u
#define G474_JSQR_JEXTEN_POS 7u
#define G474_JSQR_JSQ1_POS 9u
#define G474_JEXTSEL_TIM1_TRGO2 8u /* ADC1/ADC2 injected trigger 8: TIM1_TRGO2 */
uint32_t g474_adc_jsqr(const uint8_t *ch, uint32_t n, uint32_t jextsel);

/** The count the core reads for a raw conversion: mirrored (max - raw) when
 *  the stage's amplifier reads lower for a current into the motor. */
static inline uint16_t g474_adc_current_counts(uint32_t raw, uint32_t max, bool invert) {
  if (raw > max) {
    raw = max;
  }
  return (uint16_t)(invert ? max - raw : raw);
}

/* ---- FDCAN nominal bit timing (RM0440 "FDCAN nominal bit timing and
 *      prescaler register"; CiA 301 bitrates) ---- */

typedef struct {
  uint32_t brp;       /**< prescaler: tq = brp / f_kernel */
  uint32_t tseg1;     /**< prop + phase 1, in tq */
  uint32_t tseg2;     /**< phase 2, in tq */
  uint32_t sjw;       /**< resynchronisation jump width, in tq */
  uint32_t nbtp;      /**< FDCAN_NBTP value */
  float sample_point; /**< (1 + tseg1) / (1 + tseg1 + tseg2) */
} g474_can_timing_t;

#define G474_NBTP_NTSEG2_POS 0u /* bits 6:0, tseg2 - 1 */
#define G474_NBTP_NTSEG1_POS 8u /* bits 15:8, tseg1 - 1 */
#define G474_NBTP_NBRP_POS 16u  /* bits 24:16, brp - 1 */
#define G474_NBTP_NSJW_POS 25u  /* bits 31:25, sjw - 1 */

/** Bit timing for bitrate_bps on an FDCAN kernel clock f_kernel_Hz: the
 *  smallest prescaler giving an integer 8..25 tq per bit, the sample point
 *  nearest 87.5 % (CiA 301), SJW = tseg2. False when none fits exactly. */
bool g474_fdcan_bit_timing(uint32_t bitrate_bps, uint32_t f_kernel_Hz, g474_can_timing_t *t);

/** FDCAN1's message RAM (RM0440 "FDCAN message RAM": fixed layout per
 *  instance, 212 words): byte offsets of the sections and element sizes. */
#define G474_CANRAM_FLS 0x000u  /* 28 standard filters, 1 word each */
#define G474_CANRAM_FLE 0x070u  /* 8 extended filters, 2 words each */
#define G474_CANRAM_RF0 0x0B0u  /* RX FIFO 0: 3 elements of 18 words */
#define G474_CANRAM_RF1 0x188u  /* RX FIFO 1: 3 x 18 words */
#define G474_CANRAM_TEF 0x260u  /* TX event FIFO: 3 x 2 words */
#define G474_CANRAM_TXB 0x278u  /* TX FIFO/queue: 3 x 18 words */
#define G474_CANRAM_SIZE 0x350u /* per instance */
#define G474_CANRAM_ELEM 72u    /* bytes per RX/TX element */
/** Standard filter element: classic filter, store in RX FIFO 0, id/mask. */
uint32_t g474_can_std_filter(uint32_t id, uint32_t mask);
/** Element header words (T0/R0, T1/R1) of a classic frame. */
uint32_t g474_can_word0(uint32_t id, bool rtr);
uint32_t g474_can_word1(uint32_t dlc);

/* ---- LPUART (RM0440 "LPUART baud rate generation") ---- */

/** LPUART_BRR = 256 f_ck / baud, rounded; 0 when outside 0x300..0xFFFFF or
 *  f_ck outside [3, 4096] x baud. */
uint32_t g474_lpuart_brr(uint32_t f_ck_Hz, uint32_t baud);

/* ---- independent watchdog (RM0440 "Independent watchdog") ---- */

/** Prescaler code pr (0..6: /4 .. /256) and reload rl (0..4095) for a timeout
 *  of at least timeout_ms on the nominal LSI: the smallest prescaler that
 *  reaches it. False when above the longest. */
bool g474_iwdg_config(uint32_t timeout_ms, uint32_t f_lsi_Hz, uint32_t *pr, uint32_t *rl);
/** Timeout (ms) of pr, rl at f_lsi_Hz: 4 x 2^pr x (rl + 1) / f_lsi. */
float g474_iwdg_timeout_ms(uint32_t pr, uint32_t rl, uint32_t f_lsi_Hz);

/* ---- flash: the parameter page (RM0440 "Embedded flash memory") ---- */

/** Where the parameter page is: the last page of the flash. Dual-bank mode
 *  (FLASH_OPTR.DBANK = 1, the factory setting): 2 KB pages, 128 per bank, the
 *  last page is bank 2's page 127; single-bank: 4 KB pages, page 127. */
typedef struct {
  uint32_t addr;  /**< address of the page */
  uint32_t size;  /**< bytes */
  uint32_t page;  /**< page number within its bank (FLASH_CR.PNB) */
  uint32_t bank2; /**< 1: erase with FLASH_CR.BKER set */
} g474_nvm_geom_t;

/** The page for a flash of flash_kb (512 on the G474RE) in dual- or
 *  single-bank mode. False for a size the layout does not cover. */
bool g474_nvm_geometry(uint32_t flash_kb, bool dual_bank, g474_nvm_geom_t *g);

/** The image may use at most this many bytes of flash from 0x08000000: the
 *  last 4 KB stay free for the page in either bank mode (linker script). */
#define G474_NVM_RESERVED_BYTES 4096u

/** FLASH_ECCR (RM0440 "Flash ECC register"): ADDR_ECC bits 18:0 (byte offset
 *  in its bank in dual-bank mode, from the flash start in single-bank mode),
 *  BK_ECC bit 21, ECCD2 bit 29, ECCC bit 30, ECCD bit 31. */
#define G474_ECCR_ADDR_MASK 0x7FFFFu
#define G474_ECCR_BK (1u << 21)
#define G474_ECCR_ECCD2 (1u << 29)
#define G474_ECCR_ECCC (1u << 30)
#define G474_ECCR_ECCD (1u << 31)
/** Absolute address of the double word an ECCR value names. */
uint32_t g474_flash_ecc_address(uint32_t eccr, uint32_t flash_kb, bool dual_bank);
/** True when eccr reports a double error (ECCD or ECCD2) inside g's page. */
bool g474_flash_ecc_in_page(uint32_t eccr, uint32_t flash_kb, bool dual_bank,
                            const g474_nvm_geom_t *g);

/** What the parameter page reads as once a double ECC error was found in it
 *  (the NMI handler marks the page, g474_port.c): a header whose two words
 *  disagree, so that nvm_page_read hands over a one-byte block, which the
 *  application's CRC rejects (FW_APP_NVM_BAD_CRC: it boots on its defaults,
 *  and a 'save' erases the page and writes it anew). */
#define G474_NVM_BAD_PAGE_SIZE 4096u
extern const uint8_t g474_nvm_bad_page[G474_NVM_BAD_PAGE_SIZE];

/* ---- reference scale ---- */

/** Extend a 16-bit counter to 32 bits: the signed difference from the last
 *  extended value's low half, added to it (valid while the counter moves by
 *  less than 32768 counts between two calls). */
static inline int32_t g474_enc_extend16(int32_t last, uint32_t cnt16) {
  const int16_t d = (int16_t)(uint16_t)((cnt16 & 0xFFFFu) - ((uint32_t)last & 0xFFFFu));
  return (int32_t)((uint32_t)last + (uint32_t)(int32_t)d);
}

/* ---- the board's defaults over the drive's ---- */

/** ADC scaling of the power stage and its limits (g474_pinmap.h) over a
 *  default configuration: sensing (A and V per count, mid-scale offset, full
 *  scale, incl. the oversampler's extra bits), DC-link and current trips,
 *  injection and pulse voltages; then fw_config_derive. */
void g474_board_config(fw_config_t *cfg, uint32_t oversample);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_G474_CALC_H */
