/**
 * @file test_co_od_config.c
 * @brief Drift test: every OD entry that mirrors a fw_config_t field
 *        (protocols/od.yaml `fw_config:`) has the limits of
 *        fw_config_field() and the default of fw_config_default().
 *
 * On failure it prints the `fw_config:` section od.yaml should have
 * (paste it, then run python -m protocols.generate).
 */
#include <string.h>

#include "co_od_table.h"
#include "pmlsm/co_od.h"
#include "pmlsm/fw_ctrl.h"
#include "tinytest.h"

static float cfg_value(const fw_config_t *cfg, const fw_config_field_t *f) {
  const unsigned char *p = (const unsigned char *)cfg + f->offset;
  if (f->is_u32) {
    uint32_t v;
    memcpy(&v, p, sizeof v);
    return (float)v;
  }
  float v;
  memcpy(&v, p, sizeof v);
  return v;
}

static void print_yaml(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  printf("fw_config:\n");
  for (uint32_t k = 0; k < CO_OD_CFG_COUNT; k++) {
    const fw_config_field_t *f = fw_config_field_find(co_od_cfg_links[k].field);
    if (f == NULL) {
      continue;
    }
    printf("  %s: {min: %.9g, max: %.9g, default: %.9g, unit: \"%s\"}\n", f->name,
           (double)f->min, (double)f->max, (double)cfg_value(&cfg, f), f->unit);
  }
}

static void test_limits_and_defaults(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  TT_CHECK(CO_OD_CFG_COUNT > 0u);
  for (uint32_t k = 0; k < CO_OD_CFG_COUNT; k++) {
    const co_od_cfg_link_t *l = &co_od_cfg_links[k];
    const co_od_entry_t *e = co_od_entry(l->pos);
    const fw_config_field_t *f = fw_config_field_find(l->field);
    TT_CHECK(e != NULL);
    TT_CHECK(f != NULL);
    if (e == NULL || f == NULL) {
      printf("  field %s\n", l->field);
      continue;
    }
    float dflt = cfg_value(&cfg, f);
    if (e->type == CO_TYPE_REAL32) {
      TT_CHECK(!f->is_u32);
      TT_CHECK_NEAR(e->min_f, f->min, 0.0);
      TT_CHECK_NEAR(e->max_f, f->max, 0.0);
      TT_CHECK_NEAR(e->def_f, dflt, 0.0);
      if (e->min_f != f->min || e->max_f != f->max || e->def_f != dflt) {
        printf("  drift: 0x%04X:%u %s\n", e->index, e->sub, l->field);
      }
    } else {
      TT_CHECK(f->is_u32);
      TT_CHECK_NEAR((double)e->min_i, f->min, 0.0);
      TT_CHECK_NEAR((double)e->max_i, f->max, 0.0);
      TT_CHECK_NEAR((double)e->def_i, dflt, 0.0);
    }
  }
}

int main(int argc, char **argv) {
  if (argc > 1 && strcmp(argv[1], "--yaml") == 0) {
    print_yaml();
    return 0;
  }
  TT_RUN(test_limits_and_defaults);
  int rc = TT_SUMMARY();
  if (rc != 0) {
    print_yaml();
  }
  return rc;
}
