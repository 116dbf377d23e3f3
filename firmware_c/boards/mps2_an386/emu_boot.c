/**
 * @file emu_boot.c
 * @brief Boot block check (emu_boot.h).
 */
#include "emu_boot.h"

#include <math.h>
#include <string.h>

#include "emu_semihost.h"
#include "pmlsm/fw_app.h"
#include "pmlsm/fw_version.h"

/* The layouts the host writes (sim_fallback/_lib.py mirrors them): a change of
   either struct must change the host's mirror and this pin together, at build
   time, not in a refused boot. */
_Static_assert(sizeof(sim_plant_params_t) == 288u, "sim_plant_params_t layout changed");
_Static_assert(offsetof(sim_plant_params_t, seed) == 248u, "sim_plant_params_t layout changed");
_Static_assert(offsetof(sim_plant_params_t, ref_res_m) == 264u, "sim_plant_params_t layout");
_Static_assert(offsetof(sim_plant_params_t, ref_offset_m) == 272u, "sim_plant_params_t layout");
_Static_assert(offsetof(sim_plant_params_t, ref_fault) == 280u, "sim_plant_params_t layout");
_Static_assert(offsetof(sim_plant_params_t, ref_fault) + 2u * sizeof(uint32_t) ==
                   sizeof(sim_plant_params_t),
               "sim_plant_params_t: ref_fault and one 32-bit field end it");
_Static_assert(sizeof(fw_config_t) == 412u, "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, sensing.f_pwm_Hz) == 36u, "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, protection) == 212u, "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, protection.start_speed_max_mps) == 324u,
               "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, protection.mon_bemf_min_V) == 328u,
               "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, compensation) == 336u, "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, compensation.xsat_off6_rad) == 372u,
               "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, compensation.sogi_bumpless) == 376u,
               "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, compensation.rip_b4_rad) == 392u,
               "fw_config_t layout changed");
_Static_assert(offsetof(fw_config_t, compensation.rip6_b1_N_per_A) == 408u,
               "fw_config_t layout changed");
_Static_assert(EMU_BOOT_HEADER % 8u == 0u, "the plant's doubles must stay 8-byte aligned");
_Static_assert(EMU_BOOT_TOTAL == 876u, "boot block length");

static uint32_t le32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static int fail(emu_line_t *l, char *msg, size_t cap) {
  if (cap > 0u) {
    const size_t n = l->n < cap - 1u ? l->n : cap - 1u;
    memcpy(msg, l->buf, n);
    msg[n] = '\0';
  }
  return -1;
}

/** "emu boot block: <field> <got>, this image <want>" for a u32 field. */
static int fail_u32(const char *field, uint32_t got, uint32_t want, char *msg, size_t cap) {
  emu_line_t l = {.n = 0u};
  emu_line_str(&l, "emu boot block: ");
  emu_line_str(&l, field);
  emu_line_str(&l, " ");
  emu_line_u32(&l, got);
  emu_line_str(&l, ", this image ");
  emu_line_u32(&l, want);
  return fail(&l, msg, cap);
}

int emu_boot_read(const uint8_t *blk, size_t avail, emu_boot_t *out, char *msg, size_t cap) {
  emu_line_t l = {.n = 0u};
  emu_line_str(&l, "emu boot block: ");
  const uint32_t magic = le32(blk), format = le32(blk + 4), total = le32(blk + 8);
  if (magic != EMU_BOOT_MAGIC) {
    emu_line_str(&l, "magic ");
    emu_line_hex(&l, magic, 8u);
    emu_line_str(&l, magic == 0u ? ", expected 0x424D4550 ('PEMB'): nothing loaded at "
                                   "0x21000000 (-device loader,file=BLOCK,addr=0x21000000)"
                                 : ", expected 0x424D4550 ('PEMB'): not a boot block");
    return fail(&l, msg, cap);
  }
  if (format != EMU_BOOT_FORMAT) {
    return fail_u32("format", format, EMU_BOOT_FORMAT, msg, cap);
  }
  if (total < EMU_BOOT_HEADER || total > avail) {
    emu_line_str(&l, "length ");
    emu_line_u32(&l, total);
    emu_line_str(&l, " outside [176, 16 MiB]");
    return fail(&l, msg, cap);
  }
  const uint32_t crc = le32(blk + 12), calc = fw_app_crc32(blk + 16, total - 16u);
  if (crc != calc) {
    emu_line_str(&l, "CRC-32 ");
    emu_line_hex(&l, crc, 8u);
    emu_line_str(&l, ", computed ");
    emu_line_hex(&l, calc, 8u);
    emu_line_str(&l, " over bytes [16, ");
    emu_line_u32(&l, total);
    emu_line_str(&l, ")");
    return fail(&l, msg, cap);
  }
  const uint32_t psize = le32(blk + 16), csize = le32(blk + 20), version = le32(blk + 24);
  if (psize != (uint32_t)sizeof(sim_plant_params_t)) {
    return fail_u32("sizeof(sim_plant_params_t)", psize, (uint32_t)sizeof(sim_plant_params_t), msg,
                    cap);
  }
  if (csize != (uint32_t)sizeof(fw_config_t)) {
    return fail_u32("sizeof(fw_config_t)", csize, (uint32_t)sizeof(fw_config_t), msg, cap);
  }
  if (total != (uint32_t)EMU_BOOT_TOTAL) {
    return fail_u32("length", total, (uint32_t)EMU_BOOT_TOTAL, msg, cap);
  }
  if (version != FW_VERSION_U32) {
    emu_line_str(&l, "firmware version ");
    emu_line_hex(&l, version, 6u);
    emu_line_str(&l, ", this image ");
    emu_line_hex(&l, FW_VERSION_U32, 6u);
    emu_line_str(&l, " (" FW_VERSION_STRING ")");
    return fail(&l, msg, cap);
  }
  const uint8_t node = blk[28];
  if (node < 1u || node > 127u) {
    emu_line_str(&l, "node id ");
    emu_line_u32(&l, node);
    emu_line_str(&l, ", allowed 1..127");
    return fail(&l, msg, cap);
  }
  double x0, load;
  memcpy(&x0, blk + 32, sizeof x0);
  memcpy(&load, blk + 40, sizeof load);
  if (!isfinite(x0) || !isfinite(load)) {
    emu_line_str(&l, !isfinite(x0) ? "x0 " : "load ");
    emu_line_f64(&l, !isfinite(x0) ? x0 : load);
    emu_line_str(&l, ", expected a finite number");
    return fail(&l, msg, cap);
  }
  const char *path = (const char *)(blk + 48);
  if (memchr(path, '\0', EMU_BOOT_PATH_LEN) == NULL) {
    emu_line_str(&l, "flash file path not NUL-terminated within its 128 bytes");
    return fail(&l, msg, cap);
  }
  memcpy(&out->plant, blk + EMU_BOOT_HEADER, sizeof out->plant);
  memcpy(&out->cfg, blk + EMU_BOOT_HEADER + sizeof out->plant, sizeof out->cfg);
  const char *bad = NULL;
  if (sim_params_check(&out->plant, &bad) != 0) {
    emu_line_str(&l, "sim_plant_params_t.");
    emu_line_str(&l, bad != NULL ? bad : "?");
    emu_line_str(&l, " refused by the virtual motor (sim_params_check)");
    return fail(&l, msg, cap);
  }
  fw_config_issue_t issue;
  memset(&issue, 0, sizeof issue);
  const fw_status_t st = fw_config_check(&out->cfg, &issue);
  if (st != FW_OK && st != FW_ERR_SALIENCY) { /* low saliency: boots, refuses to enable */
    emu_line_str(&l, "fw_config_t.");
    emu_line_str(&l, issue.field != NULL ? issue.field : "?");
    emu_line_str(&l, " ");
    emu_line_f64(&l, (double)issue.value);
    if (st == FW_ERR_INCONSISTENT) {
      emu_line_str(&l, " inconsistent with the other fields");
    } else {
      emu_line_str(&l, ", allowed [");
      emu_line_f64(&l, (double)issue.min);
      emu_line_str(&l, ", ");
      emu_line_f64(&l, (double)issue.max);
      emu_line_str(&l, "]");
    }
    return fail(&l, msg, cap);
  }
  if ((float)out->plant.f_pwm_Hz != out->cfg.sensing.f_pwm_Hz) {
    emu_line_str(&l, "sim_plant_params_t.f_pwm_Hz ");
    emu_line_f64(&l, out->plant.f_pwm_Hz);
    emu_line_str(&l, " differs from fw_config_t.f_pwm_Hz ");
    emu_line_f64(&l, (double)out->cfg.sensing.f_pwm_Hz);
    emu_line_str(&l, " (the virtual motor's PWM is the drive's)");
    return fail(&l, msg, cap);
  }
  out->x0_m = x0;
  out->load_N = load;
  out->node_id = node;
  memcpy(out->nvm_path, path, EMU_BOOT_PATH_LEN);
  return 0;
}
