/**
 * @file emu_boot.h
 * @brief The emulated board's boot block (sim_fallback/_emu_blob.py): what
 *        its "hardware" is on this power-up - the virtual motor, its initial
 *        position and load, the drive's factory configuration, its node id,
 *        where its flash page is kept. QEMU loads it at EMU_BOOT_ADDR before
 *        the first instruction; the board checks every field and refuses to
 *        start on the first one that is wrong, with one line naming it.
 *
 * Layout (little endian):
 *     0  u32 magic 'PEMB'      4  u32 format        8  u32 total length
 *    12  u32 CRC-32 of [16, total)                 16  u32 sizeof(sim_plant_params_t)
 *    20  u32 sizeof(fw_config_t)                   24  u32 FW_VERSION_U32
 *    28  u8 node id, 3 reserved                    32  f64 x0 (m)   40  f64 load (N)
 *    48  char[128] flash file path (NUL-terminated)
 *   176  sim_plant_params_t     176 + P  fw_config_t
 */
#ifndef PMLSM_EMU_BOOT_H
#define PMLSM_EMU_BOOT_H

#include <stddef.h>
#include <stdint.h>

#include "pmlsm/fw_ctrl.h"
#include "pmlsm_sim.h"

#define EMU_BOOT_ADDR 0x21000000u
#define EMU_BOOT_MAGIC 0x424D4550u /* 'PEMB' */
#define EMU_BOOT_FORMAT 1u
#define EMU_BOOT_HEADER 176u
#define EMU_BOOT_PATH_LEN 128u
#define EMU_BOOT_TOTAL (EMU_BOOT_HEADER + sizeof(sim_plant_params_t) + sizeof(fw_config_t))

/** The block's content, checked. */
typedef struct {
  sim_plant_params_t plant;
  fw_config_t cfg;
  double x0_m;
  double load_N;
  uint8_t node_id;
  char nvm_path[EMU_BOOT_PATH_LEN];
} emu_boot_t;

/**
 * Check and read the block at blk (avail bytes readable there). Returns 0,
 * or -1 with a one-line message (no newline) in msg naming the field, what
 * it holds and what this image expects.
 */
int emu_boot_read(const uint8_t *blk, size_t avail, emu_boot_t *out, char *msg, size_t cap);

#endif /* PMLSM_EMU_BOOT_H */
