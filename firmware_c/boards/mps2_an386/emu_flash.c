/**
 * @file emu_flash.c
 * @brief Flash page model with a host file behind it (emu_flash.h).
 */
#include "emu_flash.h"

#include <string.h>

#include "emu_semihost.h"

/** Write mem[off, off + len) through to the file (the whole page when the
 *  file does not exist yet). */
static bool write_through(emu_flash_t *f, uint32_t off, uint32_t len) {
  int32_t h = emu_sh_open(f->path, EMU_SH_OPEN_RPB);
  if (h < 0) {
    h = emu_sh_open(f->path, EMU_SH_OPEN_WPB); /* create */
    off = 0u;
    len = EMU_FLASH_PAGE;
  }
  if (h < 0) {
    f->file_errors++;
    return false;
  }
  const bool ok = emu_sh_seek(h, off) == 0 && emu_sh_write(h, &f->mem[off], len);
  const bool closed = emu_sh_close(h) == 0;
  if (!ok || !closed) {
    f->file_errors++;
  }
  return ok && closed;
}

static bool flash_erase(void *ctx) {
  emu_flash_t *f = (emu_flash_t *)ctx;
  memset(f->mem, 0xFF, sizeof f->mem);
  f->erases++;
  return write_through(f, 0u, EMU_FLASH_PAGE);
}

static bool flash_program(void *ctx, uint32_t offset, const uint8_t *data, uint32_t len) {
  emu_flash_t *f = (emu_flash_t *)ctx;
  if (offset % EMU_FLASH_UNIT != 0u || len % EMU_FLASH_UNIT != 0u || offset > EMU_FLASH_PAGE ||
      len > EMU_FLASH_PAGE - offset) {
    return false;
  }
  for (uint32_t i = 0u; i < len; i++) {
    f->mem[offset + i] &= data[i]; /* flash clears bits only */
  }
  f->programs++;
  return write_through(f, offset, len);
}

static const uint8_t *flash_view(void *ctx) {
  return ((const emu_flash_t *)ctx)->mem;
}

bool emu_flash_init(emu_flash_t *f, const char *path) {
  memset(f, 0, sizeof *f);
  memset(f->mem, 0xFF, sizeof f->mem);
  const size_t n = path != NULL ? strlen(path) : 0u;
  if (n == 0u || n >= sizeof f->path) {
    return false;
  }
  memcpy(f->path, path, n + 1u);
  const int32_t h = emu_sh_open(f->path, EMU_SH_OPEN_RB);
  if (h >= 0) {
    (void)emu_sh_read(h, f->mem, EMU_FLASH_PAGE);
    (void)emu_sh_close(h);
  }
  return true;
}

void emu_flash_device(emu_flash_t *f, nvm_page_t *dev) {
  dev->ctx = f;
  dev->page_size = EMU_FLASH_PAGE;
  dev->prog_unit = EMU_FLASH_UNIT;
  dev->erase = flash_erase;
  dev->program = flash_program;
  dev->view = flash_view;
}
