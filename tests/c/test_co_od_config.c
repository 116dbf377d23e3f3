/**
 * @file test_co_od_config.c
 * @brief Drift test: every OD entry that mirrors a fw_config_t field
 *        (protocols/od.yaml `fw_config:`) has the limits of
 *        fw_config_field() and the default of fw_config_default().
 *
 * And: the field table generated from od.yaml (fw_config_fields.h) is the
 * one fw_config_field() serves, and fw_config_default() leaves every field at
 * the default written there: the derived ones (fw_config_derive, e.g. the
 * back-EMF levels) included, so od.yaml's value for those must be the
 * derivation's. On failure it prints what fw_config_default() gives (--yaml
 * prints them all).
 */
#include <math.h>
#include <string.h>

#include "co_od_table.h"
#include "pmlsm/co_od.h"
#include "pmlsm/fw_config_fields.h"
#include "pmlsm/fw_ctrl.h"
#include "tinytest.h"

static float cfg_value(const fw_config_t *cfg, const fw_config_field_t *f) {
  const unsigned char *p = (const unsigned char *)cfg + f->offset;
  if (f->is_int && f->is_signed) {
    int32_t v;
    memcpy(&v, p, sizeof v);
    return (float)v;
  }
  if (f->is_int) {
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
  printf("fw_config defaults (fw_config_default):\n");
  for (size_t i = 0; i < fw_config_field_count(); i++) {
    const fw_config_field_t *f = fw_config_field(i);
    printf("  %s: default %.9g\n", f->name, (double)cfg_value(&cfg, f));
  }
}

/* The generated table, field by field, against what fw_config_field() serves and
 * what fw_config_default() sets. */
static void test_generated_table_and_defaults(void) {
  fw_config_t cfg;
  fw_config_default(&cfg);
  size_t i = 0;
  TT_CHECK(fw_config_field_count() == FW_CONFIG_FIELD_COUNT);
#define F32(part_, name_, unit_, lo_, hi_, dflt_)                                         \
  do {                                                                                    \
    const fw_config_field_t *f = fw_config_field(i++);                                    \
    TT_CHECK(f != NULL && strcmp(f->name, #name_) == 0 && !f->is_int && !f->is_signed);   \
    TT_CHECK(f != NULL && f->offset == offsetof(fw_config_t, part_.name_));               \
    TT_CHECK(f != NULL && f->min == (lo_) && f->max == (hi_) && strcmp(f->unit, unit_) == 0); \
    if (cfg.part_.name_ != (dflt_)) {                                                     \
      printf("  drift: od.yaml fw_config.%s default %.9g, fw_config_default() %.9g\n",    \
             #name_, (double)(dflt_), (double)cfg.part_.name_);                           \
    }                                                                                     \
    TT_CHECK(cfg.part_.name_ == (dflt_));                                                 \
  } while (0);
#define U32(part_, name_, unit_, lo_, hi_, dflt_)                                         \
  do {                                                                                    \
    const fw_config_field_t *f = fw_config_field(i++);                                    \
    TT_CHECK(f != NULL && strcmp(f->name, #name_) == 0 && f->is_int && !f->is_signed);    \
    TT_CHECK(f != NULL && f->min == (lo_) && f->max == (hi_));                            \
    if (cfg.part_.name_ != (dflt_)) {                                                     \
      printf("  drift: od.yaml fw_config.%s default %u, fw_config_default() %u\n",        \
             #name_, (unsigned)(dflt_), (unsigned)cfg.part_.name_);                       \
    }                                                                                     \
    TT_CHECK(cfg.part_.name_ == (dflt_));                                                 \
  } while (0);
#define I32(part_, name_, unit_, lo_, hi_, dflt_)                                         \
  do {                                                                                    \
    const fw_config_field_t *f = fw_config_field(i++);                                    \
    TT_CHECK(f != NULL && strcmp(f->name, #name_) == 0 && f->is_int && f->is_signed);     \
    TT_CHECK(f != NULL && f->min == (lo_) && f->max == (hi_));                            \
    TT_CHECK(f != NULL && f->offset == offsetof(fw_config_t, part_.name_));               \
    TT_CHECK(_Generic(cfg.part_.name_, int32_t: 1, default: 0));                          \
    if (cfg.part_.name_ != (dflt_)) {                                                     \
      printf("  drift: od.yaml fw_config.%s default %d, fw_config_default() %d\n",        \
             #name_, (int)(dflt_), (int)cfg.part_.name_);                                 \
    }                                                                                     \
    TT_CHECK(cfg.part_.name_ == (dflt_));                                                 \
  } while (0);
  FW_CONFIG_FIELDS(F32, U32, I32)
#undef F32
#undef U32
#undef I32
  /* the SOGI's own clamp and the configuration range are one range */
  TT_CHECK(fw_config_field_find("sogi_k")->min == FW_SOGI_K_MIN);
  TT_CHECK(fw_config_field_find("sogi_k")->max == FW_SOGI_K_MAX);
}

static void check_scaled(const co_od_cfg_link_t *l, const co_od_entry_t *e,
                         const fw_config_field_t *f, float dflt);

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
      TT_CHECK(!f->is_int);
      TT_CHECK_NEAR(e->min_f, f->min, 0.0);
      TT_CHECK_NEAR(e->max_f, f->max, 0.0);
      TT_CHECK_NEAR(e->def_f, dflt, 0.0);
      if (e->min_f != f->min || e->max_f != f->max || e->def_f != dflt) {
        printf("  drift: 0x%04X:%u %s\n", e->index, e->sub, l->field);
      }
    } else if (l->scale == 1.0f && f->is_int) {
      /* an integer field shown as is (e.g. 0x2000 extractor, 0x605E option code): the
         entry's limits are the field's (od.yaml gives them once, for both) */
      TT_CHECK_NEAR((double)e->min_i, f->min, 0.0);
      TT_CHECK_NEAR((double)e->max_i, f->max, 0.0);
      TT_CHECK_NEAR((double)e->def_i, dflt, 0.0);
    } else {
      check_scaled(l, e, f, dflt);
    }
  }
}

/* Inclusive range of an integer OD type. */
static void type_range(uint8_t type, int64_t *lo, int64_t *hi) {
  switch (type) {
  case CO_TYPE_I8: *lo = INT8_MIN; *hi = INT8_MAX; break;
  case CO_TYPE_I16: *lo = INT16_MIN; *hi = INT16_MAX; break;
  case CO_TYPE_I32: *lo = INT32_MIN; *hi = INT32_MAX; break;
  case CO_TYPE_U8: *lo = 0; *hi = UINT8_MAX; break;
  case CO_TYPE_U16: *lo = 0; *hi = UINT16_MAX; break;
  default: *lo = 0; *hi = UINT32_MAX; break;
  }
}

/* The field value the application derives from wire value n (fw_app.c: a
 * float32 division by the scale). */
static float to_field(int64_t n, float scale) { return (float)n / scale; }

/*
 * A CiA 402 object that shows a field in wire units (value x scale, e.g.
 * 0x6080 um/s for v_max_mps): its limits hold exactly the wire values whose
 * field value the core accepts: the limit maps inside the field's range and
 * the next integer outside, unless the limit is the type's own (the field's range
 * reaches beyond the type, e.g. 0x607D in um). The default is the field default.
 */
static void check_scaled(const co_od_cfg_link_t *l, const co_od_entry_t *e,
                         const fw_config_field_t *f, float dflt) {
  int64_t lo, hi;
  type_range(e->type, &lo, &hi);
  TT_CHECK(e->type != CO_TYPE_REAL32 && l->scale > 0.0f);
  if (e->min_i > lo) {
    TT_CHECK(to_field(e->min_i, l->scale) >= f->min);
    TT_CHECK(to_field(e->min_i - 1, l->scale) < f->min);
  } else {
    TT_CHECK(e->min_i == lo);
  }
  if (e->max_i < hi) {
    TT_CHECK(to_field(e->max_i, l->scale) <= f->max);
    TT_CHECK(to_field(e->max_i + 1, l->scale) > f->max);
  } else {
    TT_CHECK(e->max_i == hi);
    /* the type's limit: the field's largest value must not be cut off */
    TT_CHECK((double)f->max * (double)l->scale >= (double)hi ||
             to_field(hi, l->scale) >= f->max);
  }
  TT_CHECK_NEAR((double)e->def_i, (double)dflt * (double)l->scale, 0.5);
  if (e->def_i != (int64_t)llround((double)dflt * (double)l->scale)) {
    printf("  drift: 0x%04X:%u %s (scale %g)\n", e->index, e->sub, l->field, (double)l->scale);
  }
}

int main(int argc, char **argv) {
  if (argc > 1 && strcmp(argv[1], "--yaml") == 0) {
    print_yaml();
    return 0;
  }
  TT_RUN(test_generated_table_and_defaults);
  TT_RUN(test_limits_and_defaults);
  int rc = TT_SUMMARY();
  if (rc != 0) {
    print_yaml();
  }
  return rc;
}
