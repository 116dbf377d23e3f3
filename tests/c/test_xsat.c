/* Tests for fw_xsat's position-ripple correction: the series from the estimate's
 * sine and cosine (double-angle formulas) against the closed form
 * a2 cos 2t + b2 sin 2t + a4 cos 4t + b4 sin 4t in double over one period; off
 * (all four 0) adds nothing and leaves the map's offset bit for bit; the cross-
 * saturation map's offset and the ripple add. */
#include <math.h>
#include <string.h>

#include "pmlsm/fw_config.h"
#include "pmlsm/fw_xsat.h"
#include "tinytest.h"

static const double PI_D = 3.14159265358979323846;

static void test_ripple_closed_form(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  cfg.compensation.rip_a2_rad = 0.0578f;
  cfg.compensation.rip_b2_rad = -0.0893f;
  cfg.compensation.rip_a4_rad = 0.004f;
  cfg.compensation.rip_b4_rad = -0.003f;
  fw_xsat_t x;
  fw_xsat_init(&x, &cfg, 1.0f / 16000.0f);
  TT_CHECK(x.rip_on == 1u);
  double dev = 0.0;
  for (int k = 0; k < 720; k++) {
    const double t = -PI_D + 2.0 * PI_D * (double)k / 720.0;
    /* the firmware's fast sine and cosine, as fw_ctrl passes them */
    const fw_sincos_f32_t sc = fw_sincos_fast_f32((float)t);
    const double want = 0.0578 * cos(2.0 * t) - 0.0893 * sin(2.0 * t) +
                        0.004 * cos(4.0 * t) - 0.003 * sin(4.0 * t);
    dev = fmax(dev, fabs((double)fw_xsat_ripple(&x, sc) - want));
    /* the map is off: the offset is the ripple alone */
    TT_CHECK(fw_xsat_offset_at(&x, sc) == fw_xsat_ripple(&x, sc));
  }
  printf("  max |ripple - closed form| = %.2e rad\n", dev);
  TT_CHECK_NEAR(dev, 0.0, 2e-5);
}

static void test_ripple_off_and_map(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  cfg.compensation.xsat_di_A = 2.0f;
  cfg.compensation.xsat_off1_rad = 0.03f;
  fw_xsat_t x;
  fw_xsat_init(&x, &cfg, 1.0f / 16000.0f);
  TT_CHECK(x.rip_on == 0u);
  for (int k = 0; k < 2000; k++) {
    fw_xsat_update(&x, 2.0f); /* the map's offset settles on 0.03 */
  }
  const fw_sincos_f32_t sc = fw_sincos_fast_f32(0.7f);
  TT_CHECK(fw_xsat_ripple(&x, sc) == 0.0f);
  TT_CHECK(fw_xsat_offset_at(&x, sc) == fw_xsat_offset(&x)); /* bit for bit */
  TT_CHECK_NEAR(fw_xsat_offset(&x), 0.03, 1e-4);
  /* one coefficient on: the map's offset plus the series */
  cfg.compensation.rip_b2_rad = 0.05f;
  fw_xsat_t y;
  fw_xsat_init(&y, &cfg, 1.0f / 16000.0f);
  y.off_rad = x.off_rad;
  TT_CHECK(y.rip_on == 1u);
  TT_CHECK_NEAR(fw_xsat_offset_at(&y, sc), (double)x.off_rad + 0.05 * sin(1.4), 2e-5);
}

int main(void) {
  TT_RUN(test_ripple_closed_form);
  TT_RUN(test_ripple_off_and_map);
  return TT_SUMMARY();
}
