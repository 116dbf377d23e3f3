/**
 * @file nvm_page.h
 * @brief The drive's non-volatile parameter block (fw_port_nvm_read/write) in
 *        one erasable flash page, for every board with internal flash (and
 *        the emulated board's flash model).
 *
 * Layout of the page: unit 0 (the first program unit, prog_unit bytes, >= 8)
 * holds the header, {uint32 len, uint32 ~len} little endian; the block's
 * bytes follow from offset prog_unit, padded with 0xFF to whole units.
 * A write erases the page, programs the block, and programs the header last:
 *   - interrupted before the header: the page reads as erased, FW_NVM_EMPTY,
 *     and the drive boots on its defaults;
 *   - a header whose two words disagree (interrupted in its own program
 *     operation): read back as a one-byte block, which the drive application
 *     rejects (FW_APP_NVM_BAD_CRC) and boots on its defaults.
 * Never a mix of two blocks that passes: the application's CRC-32 covers the
 * block. len == 0 erases the page (0x1011 'load').
 *
 * The medium is three callbacks, so this logic runs on the host in the unit
 * tests (tests/c/test_nvm_page.c), torn at every possible point.
 */
#ifndef PMLSM_BOARD_NVM_PAGE_H
#define PMLSM_BOARD_NVM_PAGE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "pmlsm/fw_port.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
  void *ctx;
  uint32_t page_size; /**< bytes of the page */
  uint32_t prog_unit; /**< bytes per program operation (8 on an STM32G4), >= 8, divides page_size */
  /** erase the page (every byte 0xFF); false on a medium error */
  bool (*erase)(void *ctx);
  /** program len bytes (a multiple of prog_unit) at offset (aligned to it) of
   *  an erased area; false on a medium error */
  bool (*program)(void *ctx, uint32_t offset, const uint8_t *data, uint32_t len);
  /** the page's present contents (memory-mapped flash) */
  const uint8_t *(*view)(void *ctx);
} nvm_page_t;

/** Largest block a page holds. */
static inline size_t nvm_page_capacity(const nvm_page_t *m) {
  return m->page_size > m->prog_unit ? (size_t)(m->page_size - m->prog_unit) : 0u;
}

/** fw_port_nvm_read on the page. */
fw_nvm_status_t nvm_page_read(const nvm_page_t *m, uint8_t *buf, size_t cap, size_t *len);

/** fw_port_nvm_write on the page (see the file comment for the order). */
fw_nvm_status_t nvm_page_write(const nvm_page_t *m, const uint8_t *data, size_t len);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_BOARD_NVM_PAGE_H */
