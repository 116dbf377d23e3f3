/**
 * @file emu_flash.h
 * @brief The emulated board's flash: one 2 KiB page in RAM (erase sets every
 *        byte to 0xFF, a program operation can only clear bits, 8-byte
 *        program unit as an STM32G4's) whose every erase and program is
 *        written through to a host file by semihosting, so that the
 *        parameter block (nvm_page.h) survives a restart of QEMU. The file
 *        is loaded at boot when it exists (missing: an erased page); it
 *        always holds the page as the flash does, so a QEMU killed during a
 *        save leaves a torn page, which nvm_page reads as empty or rejects.
 */
#ifndef PMLSM_EMU_FLASH_H
#define PMLSM_EMU_FLASH_H

#include <stdbool.h>
#include <stdint.h>

#include "nvm_page.h"

#define EMU_FLASH_PAGE 2048u
#define EMU_FLASH_UNIT 8u
#define EMU_FLASH_PATH_MAX 128u

typedef struct {
  uint8_t mem[EMU_FLASH_PAGE];
  char path[EMU_FLASH_PATH_MAX];
  uint32_t file_errors; /**< write-throughs that failed (the page in RAM stands) */
  uint32_t erases, programs;
} emu_flash_t;

/** Page from the file at path (missing or short: 0xFF for the rest). False
 *  when path is empty or too long (no non-volatile memory). */
bool emu_flash_init(emu_flash_t *f, const char *path);

/** The nvm_page device on the flash. */
void emu_flash_device(emu_flash_t *f, nvm_page_t *dev);

#endif /* PMLSM_EMU_FLASH_H */
