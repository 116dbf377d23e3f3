/**
 * @file test_g474_calc.c
 * @brief The NUCLEO-G474RE port's register values
 *        (firmware_c/boards/nucleo_g474re/g474_calc.c) against the reference
 *        manual's formulas (RM0440), computed here independently: the test
 *        decodes every register value with its own copy of the field
 *        positions, so that a wrong prescaler, range or bit position fails.
 *
 * Checked: the PLL plan (input, VCO and output ranges, 170 MHz from the
 * NUCLEO's 24 MHz crystal, the PLLCFGR fields) and the flash wait states;
 * the PWM period and compare values; the dead-time encoding against a brute
 * force over all 256 DTG values; the ADC sampling instant and window; the
 * injected sequence register; the FDCAN bit timing at every bitrate of the
 * EDS (bit time, sample point, SJW, field positions) and the message RAM
 * layout; the LPUART divider; the watchdog timeout; the parameter page's
 * place and the ECC error address; the 16-bit encoder extension; the board's
 * configuration passes the core's check.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "../../firmware_c/boards/nucleo_g474re/g474_calc.c"
#include "tinytest.h"

#define HSE 24000000u /* NUCLEO-G474RE X3 (UM2505) */

/* ---- independent decoders (RM0440 register descriptions) ---- */

static double pll_out(uint32_t cfgr, double f_src, double *f_in, double *vco) {
  const double m = (double)(((cfgr >> 4) & 0xFu) + 1u);       /* PLLM 7:4 */
  const double n = (double)((cfgr >> 8) & 0x7Fu);             /* PLLN 14:8 */
  const double r = (double)((((cfgr >> 25) & 3u) + 1u) * 2u); /* PLLR 26:25 */
  *f_in = f_src / m;
  *vco = *f_in * n;
  return *vco / r;
}

/* dead time in tDTS of a DTG value (RM0440 TIMx_BDTR, DTG[7:0]) */
static unsigned dtg_ticks(unsigned dtg) {
  if ((dtg & 0x80u) == 0u)
    return dtg; /* 0xx xxxxx */
  if ((dtg & 0xC0u) == 0x80u)
    return (64u + (dtg & 0x3Fu)) * 2u; /* 10x xxxxx */
  if ((dtg & 0xE0u) == 0xC0u)
    return (32u + (dtg & 0x1Fu)) * 8u; /* 110 xxxxx */
  return (32u + (dtg & 0x1Fu)) * 16u;  /* 111 xxxxx */
}

static void test_clock_plan(void) {
  g474_clock_plan_t p;
  TT_CHECK(g474_clock_plan(HSE, 170000000u, &p));
  double f_in, vco;
  const double f = pll_out(p.pllcfgr, HSE, &f_in, &vco);
  TT_CHECK_NEAR(f, 170e6, 1e-3);
  TT_CHECK(f_in >= 2.66e6 && f_in <= 16e6); /* PLL input range */
  TT_CHECK(vco >= 96e6 && vco <= 344e6);    /* VCO range */
  TT_CHECK((p.pllcfgr & 3u) == 3u);         /* PLLSRC = HSE */
  TT_CHECK((p.pllcfgr >> 24 & 1u) == 1u);   /* PLLREN */
  TT_CHECK(p.pll_m == 6u && p.pll_n == 85u && p.pll_r == 2u);
  TT_CHECK(p.f_vco_Hz == 340000000u);
  TT_CHECK(p.boost);          /* > 150 MHz needs range 1 boost */
  TT_CHECK(p.flash_ws == 4u); /* 136 < 170 <= 170 MHz */
  /* the exact 24 kHz alternative, and a clock the PLL cannot make */
  TT_CHECK(g474_clock_plan(HSE, 168000000u, &p));
  TT_CHECK_NEAR(pll_out(p.pllcfgr, HSE, &f_in, &vco), 168e6, 1e-3);
  TT_CHECK(vco <= 344e6 && f_in >= 2.66e6);
  TT_CHECK(!g474_clock_plan(HSE, 171000000u, &p)); /* above the maximum */
  TT_CHECK(!g474_clock_plan(HSE, 169999999u, &p)); /* no integer N */
  /* from a 16 MHz source (HSI-like) the same 170 MHz: M 4, N 85 */
  TT_CHECK(g474_clock_plan(16000000u, 170000000u, &p));
  TT_CHECK_NEAR(pll_out(p.pllcfgr, 16e6, &f_in, &vco), 170e6, 1e-3);
}

static void test_flash_latency(void) {
  /* RM0440 wait-state table: boost 34/68/102/136/170, normal 30/60/90/120/150 MHz */
  static const uint32_t boost_max[5] = {34000000u, 68000000u, 102000000u, 136000000u, 170000000u};
  static const uint32_t norm_max[5] = {30000000u, 60000000u, 90000000u, 120000000u, 150000000u};
  for (uint32_t ws = 0; ws < 5u; ws++) {
    TT_CHECK(g474_flash_latency(boost_max[ws], true) == ws);
    TT_CHECK(g474_flash_latency(norm_max[ws], false) == ws);
    if (ws < 4u) {
      TT_CHECK(g474_flash_latency(boost_max[ws] + 1u, true) == ws + 1u);
      TT_CHECK(g474_flash_latency(norm_max[ws] + 1u, false) == ws + 1u);
    }
  }
  TT_CHECK(g474_flash_latency(170000001u, true) == 0xFFFFFFFFu);
  TT_CHECK(g474_flash_latency(150000001u, false) == 0xFFFFFFFFu);
}

static void test_pwm(void) {
  const uint32_t arr = g474_pwm_arr(170000000u, 24000u);
  TT_CHECK(arr == 3542u); /* 170e6 / (2 x 24e3) = 3541.67 */
  /* centre-aligned: one period is 2 ARR timer ticks */
  TT_CHECK_NEAR(g474_pwm_freq_Hz(170000000u, arr), 170e6 / (2.0 * 3542.0), 0.01);
  TT_CHECK(fabs(170e6 / (2.0 * arr) - 24000.0) / 24000.0 < 1e-4); /* 96 ppm */
  TT_CHECK(g474_pwm_arr(168000000u, 24000u) == 3500u);            /* exact at 168 MHz */
  /* compare = duty x ARR (PWM mode 1: active while CNT < CCR, 2 CCR of 2 ARR ticks) */
  int bad = 0;
  for (int i = 0; i <= 1000; i++) {
    const float d = (float)i / 1000.0f;
    const uint32_t c = g474_pwm_compare(d, arr);
    bad += fabs((double)c / arr - (double)d) > 0.5 / arr + 1e-7 || c > arr;
  }
  TT_CHECK(bad == 0);
  TT_CHECK(g474_pwm_compare(0.5f, arr) == 1771u);
  TT_CHECK(g474_pwm_compare(-0.2f, arr) == 0u);
  TT_CHECK(g474_pwm_compare(1.3f, arr) == arr);
  TT_CHECK(g474_pwm_compare(NAN, arr) == arr / 2u);
}

static void test_dead_time(void) {
  const uint32_t f = 170000000u; /* CKD = 00: tDTS = 1 / f_CK_INT */
  float got = 0.0f;
  TT_CHECK(g474_dead_time_dtg(800u, f, &got) == 0x84u); /* (64 + 4) x 2 = 136 tDTS */
  TT_CHECK_NEAR(got, 136.0 / 170e6 * 1e9, 1e-3);
  TT_CHECK(g474_dead_time_dtg(0u, f, NULL) == 0u);
  int bad = 0;
  for (uint32_t ns = 0; ns <= 6000u; ns += 7u) {
    const double need = ceil((double)ns * f / 1e9 - 1e-9);
    const uint8_t dtg = g474_dead_time_dtg(ns, f, &got);
    /* the smallest dead time over all 256 encodings that is at least `need` */
    unsigned best = 0xFFFFFFFFu;
    for (unsigned v = 0; v < 256u; v++) {
      const unsigned t = dtg_ticks(v);
      if (t >= need && t < best)
        best = t;
    }
    if (best == 0xFFFFFFFFu) {
      bad += dtg != 0xFFu; /* beyond 1008 tDTS: the largest */
    } else {
      bad += dtg_ticks(dtg) != best || fabs(got - best / (double)f * 1e9) > 1e-2;
    }
  }
  TT_CHECK(bad == 0);
}

static void test_adc_instant(void) {
  /* 42.5 MHz ADC (HCLK / 4), 6.5-cycle sampling, 12.5-cycle conversion, 3 cycles latency */
  g474_adc_timing_t t = {170000000u, 4u, 13u, 25u, 6u, 1u};
  const uint32_t arr = 3542u;
  /* independently, in ADC cycles: rank 1 samples [lat, lat + smp], rank 2 one
     conversion later; the middle of the two goes on the peak */
  const double lat = 3.0, smp = 6.5, conv = 12.5;
  const double first = lat, last_end = lat + (smp + conv) + smp;
  TT_CHECK(g474_adc_span_ticks(&t) == (uint32_t)lround((last_end - first) * 4.0));
  TT_CHECK(g474_adc_trigger_ticks(&t) == (uint32_t)lround((first + last_end) / 2.0 * 4.0));
  TT_CHECK(g474_adc_trigger_ticks(&t) == 63u);
  /* the samples (600 ns) fit the low-side window up to this duty */
  TT_CHECK_NEAR(g474_adc_max_duty(&t, arr), 1.0 - 102.0 / (2.0 * arr), 1e-6);
  TT_CHECK(g474_adc_max_duty(&t, arr) > 0.98f);
  /* x4 oversampling: 4 conversions per rank, 3.3 us, duty limit about 0.92 */
  t.oversample = 4u;
  const double last4 = lat + 7.0 * (smp + conv) + smp;
  TT_CHECK(g474_adc_span_ticks(&t) == (uint32_t)lround((last4 - first) * 4.0));
  TT_CHECK(g474_adc_max_duty(&t, arr) < 0.93f && g474_adc_max_duty(&t, arr) > 0.91f);
  /* JSQR: JL 1:0 = n - 1, JEXTSEL 6:2, JEXTEN 8:7 = 01 rising, JSQk at 9 + 6 (k - 1) */
  const uint8_t ch[2] = {1u, 6u};
  const uint32_t j = g474_adc_jsqr(ch, 2u, G474_JEXTSEL_TIM1_TRGO2);
  TT_CHECK((j & 3u) == 1u);
  TT_CHECK(((j >> 2) & 0x1Fu) == 8u); /* TIM1_TRGO2 for ADC1/ADC2 injected */
  TT_CHECK(((j >> 7) & 3u) == 1u);
  TT_CHECK(((j >> 9) & 0x1Fu) == 1u && ((j >> 15) & 0x1Fu) == 6u);
  TT_CHECK((j >> 21) == 0u);
  TT_CHECK(g474_adc_jsqr(ch, 0u, 8u) == 0u && g474_adc_jsqr(ch, 5u, 8u) == 0u);
  /* the mirrored current counts */
  TT_CHECK(g474_adc_current_counts(0u, 4095u, true) == 4095u);
  TT_CHECK(g474_adc_current_counts(4095u, 4095u, true) == 0u);
  TT_CHECK(g474_adc_current_counts(1000u, 4095u, false) == 1000u);
  TT_CHECK(g474_adc_current_counts(5000u, 4095u, false) == 4095u);
}

static void test_fdcan_timing(void) {
  /* every bitrate the EDS lists (BaudRate_125/250/500/1000 = 1) on the 24 MHz HSE,
     and on PCLK1 = 170 MHz */
  static const uint32_t rates[4] = {125000u, 250000u, 500000u, 1000000u};
  static const uint32_t clocks[2] = {HSE, 170000000u};
  for (int c = 0; c < 2; c++) {
    for (int i = 0; i < 4; i++) {
      g474_can_timing_t t;
      TT_CHECK(g474_fdcan_bit_timing(rates[i], clocks[c], &t));
      /* decode FDCAN_NBTP: NSJW 31:25, NBRP 24:16, NTSEG1 15:8, NTSEG2 6:0, each +1 */
      const uint32_t sjw = ((t.nbtp >> 25) & 0x7Fu) + 1u;
      const uint32_t brp = ((t.nbtp >> 16) & 0x1FFu) + 1u;
      const uint32_t ts1 = ((t.nbtp >> 8) & 0xFFu) + 1u;
      const uint32_t ts2 = (t.nbtp & 0x7Fu) + 1u;
      TT_CHECK((t.nbtp & 0x80u) == 0u); /* bit 7 reserved */
      const uint32_t ntq = 1u + ts1 + ts2;
      /* bit time = (1 + TSEG1 + TSEG2) tq, tq = BRP / f: exactly one bit */
      TT_CHECK((uint64_t)brp * ntq * rates[i] == clocks[c]);
      TT_CHECK(ntq >= 8u && ntq <= 25u);
      const double sp = (1.0 + ts1) / ntq;
      TT_CHECK(sp >= 0.85 && sp <= 0.90);
      TT_CHECK_NEAR(t.sample_point, sp, 1e-6);
      TT_CHECK(sjw <= ts2 && sjw >= 1u);
    }
  }
  g474_can_timing_t t;
  TT_CHECK(g474_fdcan_bit_timing(1000000u, HSE, &t));
  TT_CHECK(t.brp == 1u && t.tseg1 == 20u && t.tseg2 == 3u); /* 24 tq, 87.5 % */
  TT_CHECK(g474_fdcan_bit_timing(125000u, HSE, &t) && t.brp == 8u);
  /* the values the board README lists */
  static const uint32_t nbtp[4] = {0x04071302u, 0x04031302u, 0x04011302u, 0x04001302u};
  for (int i = 0; i < 4; i++) {
    TT_CHECK(g474_fdcan_bit_timing(rates[i], HSE, &t) && t.nbtp == nbtp[i]);
  }
  TT_CHECK(!g474_fdcan_bit_timing(1000000u, 7000000u, &t)); /* 7 tq: too few */
  /* message RAM (RM0440: 28 std filters x 1 word, 8 ext x 2, RX FIFO 0/1 3 x 18,
     TX event 3 x 2, TX 3 x 18 words) */
  TT_CHECK(G474_CANRAM_FLE == 28u * 4u);
  TT_CHECK(G474_CANRAM_RF0 == G474_CANRAM_FLE + 8u * 8u);
  TT_CHECK(G474_CANRAM_RF1 == G474_CANRAM_RF0 + 3u * 72u);
  TT_CHECK(G474_CANRAM_TEF == G474_CANRAM_RF1 + 3u * 72u);
  TT_CHECK(G474_CANRAM_TXB == G474_CANRAM_TEF + 3u * 8u);
  TT_CHECK(G474_CANRAM_SIZE == G474_CANRAM_TXB + 3u * 72u && G474_CANRAM_SIZE == 212u * 4u);
  /* element words: standard id 28:18, RTR 29, XTD 30 clear; DLC 19:16 */
  const uint32_t w0 = g474_can_word0(0x701u, false), w1 = g474_can_word1(8u);
  TT_CHECK(((w0 >> 18) & 0x7FFu) == 0x701u && (w0 & (7u << 29)) == 0u);
  TT_CHECK((g474_can_word0(0x123u, true) >> 29) == 1u);
  TT_CHECK(((w1 >> 16) & 0xFu) == 8u && (w1 & ~(0xFu << 16)) == 0u);
  TT_CHECK(((g474_can_word1(15u) >> 16) & 0xFu) == 8u);
  /* standard filter: SFT 31:30 = 10 classic, SFEC 29:27 = 001 FIFO 0, SFID2 mask 0 */
  const uint32_t f = g474_can_std_filter(0u, 0u);
  TT_CHECK((f >> 30) == 2u && ((f >> 27) & 7u) == 1u && (f & 0x7FFu) == 0u);
}

static void test_lpuart_brr(void) {
  const uint32_t brr = g474_lpuart_brr(170000000u, 921600u);
  TT_CHECK(brr == 47222u); /* 256 x 170e6 / 921600 = 47222.2 */
  const double baud = 256.0 * 170e6 / brr;
  TT_CHECK(fabs(baud - 921600.0) / 921600.0 < 1e-4);
  TT_CHECK(g474_lpuart_brr(170000000u, 115200u) == 377778u);
  TT_CHECK(g474_lpuart_brr(170000000u, 9600u) == 0u); /* needs the prescaler */
}

static void test_iwdg(void) {
  uint32_t pr = 9u, rl = 9999u;
  TT_CHECK(g474_iwdg_config(250u, 32000u, &pr, &rl));
  /* independent: 4 x 2^PR x (RL + 1) / f_LSI seconds, RL 12 bits, PR 0..6 */
  const double t = 4.0 * (1u << pr) * (rl + 1u) / 32000.0;
  TT_CHECK(t >= 0.250 && t < 0.250 + 4.0 * (1u << pr) / 32000.0);
  TT_CHECK(rl <= 4095u && pr <= 6u);
  TT_CHECK_NEAR(g474_iwdg_timeout_ms(pr, rl, 32000u), t * 1e3, 1e-3);
  TT_CHECK(g474_iwdg_config(32000u, 32000u, &pr, &rl) && pr == 6u); /* 256 x 4096 / 32 kHz */
  TT_CHECK(!g474_iwdg_config(40000u, 32000u, &pr, &rl));            /* beyond 32.8 s */
}

static void test_nvm_page_place(void) {
  g474_nvm_geom_t g;
  TT_CHECK(g474_nvm_geometry(512u, true, &g));
  TT_CHECK(g.addr == 0x0807F800u && g.size == 2048u && g.page == 127u && g.bank2 == 1u);
  TT_CHECK(g.addr + g.size == 0x08000000u + 512u * 1024u); /* the last page */
  TT_CHECK(g.addr >= 0x08000000u + 512u * 1024u - G474_NVM_RESERVED_BYTES);
  TT_CHECK(g474_nvm_geometry(512u, false, &g));
  TT_CHECK(g.addr == 0x0807F000u && g.size == 4096u && g.page == 127u && g.bank2 == 0u);
  TT_CHECK(g.addr >= 0x08000000u + 512u * 1024u - G474_NVM_RESERVED_BYTES);
  TT_CHECK(!g474_nvm_geometry(300u, true, &g));
  /* ECC: bank 2, offset 0x3F808 (page 127 of 2 KB) with ECCD: inside the page */
  TT_CHECK(g474_nvm_geometry(512u, true, &g));
  const uint32_t e = (1u << 31) | (1u << 21) | 0x3F808u;
  TT_CHECK(g474_flash_ecc_address(e, 512u, true) == 0x0807F808u);
  TT_CHECK(g474_flash_ecc_in_page(e, 512u, true, &g));
  TT_CHECK(!g474_flash_ecc_in_page(e & ~(1u << 31), 512u, true, &g)); /* no double error */
  TT_CHECK(g474_flash_ecc_in_page((e & ~(1u << 31)) | (1u << 29), 512u, true, &g)); /* ECCD2 */
  TT_CHECK(!g474_flash_ecc_in_page(e & ~(1u << 21), 512u, true, &g)); /* bank 1: code */
  TT_CHECK(!g474_flash_ecc_in_page((1u << 31) | (1u << 30), 512u, true, &g));
  TT_CHECK(g474_nvm_geometry(512u, false, &g));
  TT_CHECK(g474_flash_ecc_in_page((1u << 31) | 0x7F010u, 512u, false, &g));
  /* the bad-page image is what nvm_page_read rejects as a torn header */
  TT_CHECK(g474_nvm_bad_page[0] == 0u && g474_nvm_bad_page[4] == 0u);
}

static void test_encoder_extend(void) {
  int32_t x = 0;
  int32_t truth = 0;
  uint32_t cnt = 0u;
  int bad = 0;
  /* forwards across the 16-bit wrap, then back below zero, steps < 32768 */
  static const int32_t steps[] = {30000, 30000, 30000, -1, 5, -32000, -32000, -32000, -32000, 7};
  for (size_t i = 0; i < sizeof steps / sizeof steps[0]; i++) {
    truth += steps[i];
    cnt = (uint32_t)truth & 0xFFFFu;
    x = g474_enc_extend16(x, cnt);
    bad += x != truth;
  }
  TT_CHECK(bad == 0);
  TT_CHECK(x == truth && truth < 0);
}

static void test_board_config_passes_check(void) {
  for (uint32_t ovs = 1u; ovs <= 4u; ovs += 3u) {
    fw_config_t cfg;
    fw_config_default(&cfg);
    g474_board_config(&cfg, ovs);
    fw_config_issue_t issue;
    memset(&issue, 0, sizeof issue);
    const fw_status_t st = fw_config_check(&cfg, &issue);
    if (st != FW_OK) {
      printf("  config refused: %s = %g [%g, %g]\n", issue.field ? issue.field : "?",
             (double)issue.value, (double)issue.min, (double)issue.max);
    }
    TT_CHECK(st == FW_OK);
    /* 3.3 V / 4096 / (10 mOhm x 5.18) per 12-bit count */
    const double a12 = 3.3 / 4096.0 / (0.010 * 5.18);
    TT_CHECK_NEAR(cfg.sensing.adc_A_per_count, a12 / (ovs == 4u ? 2.0 : 1.0), 1e-7);
    const double fs_A = (cfg.sensing.adc_max_count + 1.0 - cfg.sensing.adc_offset_counts) *
                        cfg.sensing.adc_A_per_count;
    TT_CHECK(cfg.protection.i_trip_A < fs_A); /* the trip is inside the sensor's range */
    TT_CHECK(cfg.loops.i_max_A < cfg.protection.i_trip_A);
    const double fs_V = cfg.sensing.adc_max_count * (double)cfg.sensing.adc_V_per_count;
    TT_CHECK(cfg.protection.u_dc_max_V < fs_V); /* 63 V full scale */
    TT_CHECK(cfg.sensing.adc_max_count == (ovs == 4u ? 8191u : 4095u));
  }
}

int main(void) {
  TT_RUN(test_clock_plan);
  TT_RUN(test_flash_latency);
  TT_RUN(test_pwm);
  TT_RUN(test_dead_time);
  TT_RUN(test_adc_instant);
  TT_RUN(test_fdcan_timing);
  TT_RUN(test_lpuart_brr);
  TT_RUN(test_iwdg);
  TT_RUN(test_nvm_page_place);
  TT_RUN(test_encoder_extend);
  TT_RUN(test_board_config_passes_check);
  return TT_SUMMARY();
}
