/**
 * @file g474_calc.c
 * @brief The register values of the NUCLEO-G474RE port as pure functions
 *        (g474_calc.h). Compiled into the image and, on the host, into
 *        tests/c/test_g474_calc.c.
 */
#include "g474_calc.h"

#include "g474_pinmap.h"

bool g474_clock_plan(uint32_t f_hse_Hz, uint32_t f_sys_Hz, g474_clock_plan_t *plan) {
  static const uint32_t rs[4] = {2u, 4u, 6u, 8u};
  if (plan == NULL || f_hse_Hz == 0u || f_sys_Hz == 0u || f_sys_Hz > 170000000u) {
    return false;
  }
  for (uint32_t m = 1u; m <= 16u; m++) {
    /* PLL input 2.66 .. 16 MHz (RM0440, "PLL" in the clock tree; datasheet) */
    if ((uint64_t)f_hse_Hz < 2660000ull * m || f_hse_Hz > 16000000u * m) {
      continue;
    }
    for (uint32_t i = 0u; i < 4u; i++) {
      const uint64_t vco = (uint64_t)f_sys_Hz * rs[i];
      if (vco < 96000000ull || vco > 344000000ull) {
        continue;
      }
      const uint64_t num = vco * m; /* N = VCO / (f_hse / M) */
      if (num % f_hse_Hz != 0u) {
        continue;
      }
      const uint64_t n = num / f_hse_Hz;
      if (n < 8u || n > 127u) {
        continue;
      }
      plan->f_in_Hz = f_hse_Hz;
      plan->pll_m = m;
      plan->pll_n = (uint32_t)n;
      plan->pll_r = rs[i];
      plan->f_vco_Hz = (uint32_t)vco;
      plan->f_sys_Hz = f_sys_Hz;
      plan->boost = f_sys_Hz > 150000000u;
      plan->flash_ws = g474_flash_latency(f_sys_Hz, plan->boost);
      plan->pllcfgr = G474_PLLCFGR_SRC_HSE | ((m - 1u) << G474_PLLCFGR_M_POS) |
                      ((uint32_t)n << G474_PLLCFGR_N_POS) | G474_PLLCFGR_REN |
                      ((rs[i] / 2u - 1u) << G474_PLLCFGR_R_POS);
      return true;
    }
  }
  return false;
}

uint32_t g474_flash_latency(uint32_t hclk_Hz, bool boost) {
  const uint32_t step = boost ? 34000000u : 30000000u; /* per wait state */
  for (uint32_t ws = 0u; ws <= 4u; ws++) {
    if (hclk_Hz <= step * (ws + 1u)) {
      return ws;
    }
  }
  return 0xFFFFFFFFu;
}

uint32_t g474_pwm_arr(uint32_t f_tim_Hz, uint32_t f_pwm_Hz) {
  if (f_pwm_Hz == 0u) {
    return 0u;
  }
  const uint64_t den = 2ull * f_pwm_Hz;
  return (uint32_t)(((uint64_t)f_tim_Hz + den / 2u) / den);
}

float g474_pwm_freq_Hz(uint32_t f_tim_Hz, uint32_t arr) {
  return arr == 0u ? 0.0f : (float)f_tim_Hz / (2.0f * (float)arr);
}

uint8_t g474_dead_time_dtg(uint32_t dead_ns, uint32_t f_dts_Hz, float *got_ns) {
  /* ticks of tDTS needed, rounded up */
  const uint64_t n = ((uint64_t)dead_ns * f_dts_Hz + 999999999ull) / 1000000000ull;
  uint32_t dtg;
  uint32_t ticks;
  if (n <= 127u) { /* DTG[7] = 0: DT = DTG[7:0] x tDTS */
    dtg = (uint32_t)n;
    ticks = dtg;
  } else if (n <= 254u) { /* DTG[7:6] = 10: DT = (64 + DTG[5:0]) x 2 tDTS */
    const uint32_t k = (uint32_t)((n + 1u) / 2u) - 64u;
    dtg = 0x80u | k;
    ticks = (64u + k) * 2u;
  } else if (n <= 504u) { /* DTG[7:5] = 110: DT = (32 + DTG[4:0]) x 8 tDTS */
    const uint32_t k = (uint32_t)((n + 7u) / 8u) - 32u;
    dtg = 0xC0u | k;
    ticks = (32u + k) * 8u;
  } else if (n <= 1008u) { /* DTG[7:5] = 111: DT = (32 + DTG[4:0]) x 16 tDTS */
    const uint32_t k = (uint32_t)((n + 15u) / 16u) - 32u;
    dtg = 0xE0u | k;
    ticks = (32u + k) * 16u;
  } else {
    dtg = 0xFFu;
    ticks = 1008u;
  }
  if (got_ns != NULL) {
    *got_ns = (float)ticks * 1.0e9f / (float)f_dts_Hz;
  }
  return (uint8_t)dtg;
}

uint32_t g474_adc_span_ticks(const g474_adc_timing_t *t) {
  /* half ADC cycles: 2 ranks x oversample conversions, the last one's sampling */
  const uint32_t per_conv = t->smp_x2 + t->conv_x2;
  const uint32_t span_x2 = (2u * t->oversample - 1u) * per_conv + t->smp_x2;
  return (span_x2 * t->adc_div + 1u) / 2u;
}

uint32_t g474_adc_trigger_ticks(const g474_adc_timing_t *t) {
  const uint32_t per_conv = t->smp_x2 + t->conv_x2;
  const uint32_t span_x2 = (2u * t->oversample - 1u) * per_conv + t->smp_x2;
  /* latency + half the span, in half ADC cycles, to timer ticks */
  return ((2u * t->latency_x2 + span_x2) * t->adc_div + 2u) / 4u;
}

float g474_adc_max_duty(const g474_adc_timing_t *t, uint32_t arr) {
  if (arr == 0u) {
    return 0.0f;
  }
  return 1.0f - (float)g474_adc_span_ticks(t) / (2.0f * (float)arr);
}

uint32_t g474_adc_jsqr(const uint8_t *ch, uint32_t n, uint32_t jextsel) {
  if (ch == NULL || n == 0u || n > 4u) {
    return 0u;
  }
  uint32_t v = ((n - 1u) << G474_JSQR_JL_POS) | ((jextsel & 0x1Fu) << G474_JSQR_JEXTSEL_POS) |
               (1u << G474_JSQR_JEXTEN_POS);
  for (uint32_t i = 0u; i < n; i++) {
    v |= ((uint32_t)ch[i] & 0x1Fu) << (G474_JSQR_JSQ1_POS + 6u * i);
  }
  return v;
}

bool g474_fdcan_bit_timing(uint32_t bitrate_bps, uint32_t f_kernel_Hz, g474_can_timing_t *t) {
  if (t == NULL || bitrate_bps == 0u) {
    return false;
  }
  for (uint32_t brp = 1u; brp <= 512u; brp++) {
    const uint64_t div = (uint64_t)brp * bitrate_bps;
    if (f_kernel_Hz % div != 0u) {
      continue;
    }
    const uint32_t ntq = (uint32_t)(f_kernel_Hz / div);
    if (ntq > 25u) {
      continue; /* fewer tq per bit with a larger prescaler */
    }
    if (ntq < 8u) {
      return false; /* only fewer from here on */
    }
    /* sample point (1 + tseg1) / ntq nearest 87.5 %: 1 + tseg1 = round(0.875 ntq) */
    const uint32_t before = (7u * ntq + 4u) / 8u;
    const uint32_t tseg1 = before - 1u;
    const uint32_t tseg2 = ntq - before;
    if (tseg1 < 2u || tseg1 > 256u || tseg2 < 1u || tseg2 > 128u) {
      continue;
    }
    t->brp = brp;
    t->tseg1 = tseg1;
    t->tseg2 = tseg2;
    t->sjw = tseg2;
    t->sample_point = (float)before / (float)ntq;
    t->nbtp = ((t->sjw - 1u) << G474_NBTP_NSJW_POS) | ((brp - 1u) << G474_NBTP_NBRP_POS) |
              ((tseg1 - 1u) << G474_NBTP_NTSEG1_POS) | ((tseg2 - 1u) << G474_NBTP_NTSEG2_POS);
    return true;
  }
  return false;
}

uint32_t g474_can_std_filter(uint32_t id, uint32_t mask) {
  /* SFT = 10 classic (id, mask), SFEC = 001 store in RX FIFO 0, SFID1, SFID2 */
  return (2u << 30) | (1u << 27) | ((id & 0x7FFu) << 16) | (mask & 0x7FFu);
}

uint32_t g474_can_word0(uint32_t id, bool rtr) {
  return (rtr ? (1u << 29) : 0u) | ((id & 0x7FFu) << 18); /* XTD = 0, standard id 28:18 */
}

uint32_t g474_can_word1(uint32_t dlc) {
  return (dlc > 8u ? 8u : dlc) << 16; /* DLC 19:16, FDF = BRS = EFC = 0 */
}

uint32_t g474_lpuart_brr(uint32_t f_ck_Hz, uint32_t baud) {
  if (baud == 0u || (uint64_t)f_ck_Hz < 3ull * baud || (uint64_t)f_ck_Hz > 4096ull * baud) {
    return 0u;
  }
  const uint64_t brr = (256ull * f_ck_Hz + baud / 2u) / baud;
  if (brr < 0x300u || brr > 0xFFFFFu) {
    return 0u;
  }
  return (uint32_t)brr;
}

bool g474_iwdg_config(uint32_t timeout_ms, uint32_t f_lsi_Hz, uint32_t *pr, uint32_t *rl) {
  if (pr == NULL || rl == NULL || timeout_ms == 0u) {
    return false;
  }
  for (uint32_t p = 0u; p <= 6u; p++) {
    const uint64_t div = 1000ull * (4u << p);
    const uint64_t ticks = ((uint64_t)timeout_ms * f_lsi_Hz + div - 1u) / div;
    if (ticks >= 1u && ticks <= 4096u) {
      *pr = p;
      *rl = (uint32_t)ticks - 1u;
      return true;
    }
  }
  return false;
}

float g474_iwdg_timeout_ms(uint32_t pr, uint32_t rl, uint32_t f_lsi_Hz) {
  return 1000.0f * (float)(4u << pr) * (float)(rl + 1u) / (float)f_lsi_Hz;
}

bool g474_nvm_geometry(uint32_t flash_kb, bool dual_bank, g474_nvm_geom_t *g) {
  if (g == NULL || (flash_kb != 128u && flash_kb != 256u && flash_kb != 512u)) {
    return false;
  }
  const uint32_t bytes = flash_kb * 1024u;
  if (dual_bank) {
    g->size = 2048u;
    g->page = bytes / 2u / 2048u - 1u;
    g->bank2 = 1u;
  } else {
    g->size = 4096u;
    g->page = bytes / 4096u - 1u;
    g->bank2 = 0u;
  }
  g->addr = 0x08000000u + bytes - g->size;
  return true;
}

/* all zeros: header length 0 with check 0, which is not ~0 */
const uint8_t g474_nvm_bad_page[G474_NVM_BAD_PAGE_SIZE] = {0};

uint32_t g474_flash_ecc_address(uint32_t eccr, uint32_t flash_kb, bool dual_bank) {
  const uint32_t off = eccr & G474_ECCR_ADDR_MASK;
  const uint32_t bank = (dual_bank && (eccr & G474_ECCR_BK) != 0u) ? flash_kb * 1024u / 2u : 0u;
  return 0x08000000u + bank + off;
}

bool g474_flash_ecc_in_page(uint32_t eccr, uint32_t flash_kb, bool dual_bank,
                            const g474_nvm_geom_t *g) {
  if (g == NULL || (eccr & (G474_ECCR_ECCD | G474_ECCR_ECCD2)) == 0u) {
    return false;
  }
  const uint32_t a = g474_flash_ecc_address(eccr, flash_kb, dual_bank);
  return a >= g->addr && a - g->addr < g->size;
}

void g474_board_config(fw_config_t *cfg, uint32_t oversample) {
  if (cfg == NULL) {
    return;
  }
  /* x4 oversampling shifted right by one: 13-bit results, twice the counts */
  const float k = oversample == 4u ? 2.0f : 1.0f;
  const float volt_per_count = G474_VREF_V / 4096.0f;
  cfg->sensing.adc_A_per_count = volt_per_count / (G474_SHUNT_OHM * G474_AMP_GAIN) / k;
  cfg->sensing.adc_offset_counts = 2048.0f * k;
  cfg->sensing.adc_V_per_count = volt_per_count * G474_UDC_DIVIDER / k;
  cfg->sensing.adc_max_count = oversample == 4u ? 8191u : 4095u;
  cfg->protection.u_dc_min_V = G474_U_DC_MIN_V;
  cfg->protection.u_dc_max_V = G474_U_DC_MAX_V;
  cfg->protection.i_trip_A = G474_I_TRIP_A;
  cfg->loops.i_max_A = G474_I_MAX_A;
  cfg->estimator.u_inj_V = G474_U_INJ_V;
  cfg->estimator.pol_pulse_V = G474_POL_PULSE_V;
  fw_config_derive(cfg);
}
