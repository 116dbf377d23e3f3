/**
 * @file emu_semihost.h
 * @brief ARM semihosting (QEMU -semihosting-config enable=on,target=native):
 *        the emulated board's console lines, its exit status, and the host
 *        file behind its flash page. ARM "Semihosting for AArch32 and
 *        AArch64" v2.0: BKPT 0xAB on M profile, operation in r0, parameter
 *        block in r1, result in r0.
 */
#ifndef PMLSM_EMU_SEMIHOST_H
#define PMLSM_EMU_SEMIHOST_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define EMU_SH_OPEN_RB 1u  /**< SYS_OPEN mode "rb" */
#define EMU_SH_OPEN_RPB 3u /**< "r+b" */
#define EMU_SH_OPEN_WPB 7u /**< "w+b" */

/** Write a NUL-terminated string to the semihosting console (SYS_WRITE0). */
void emu_sh_write0(const char *s);

/** Exit QEMU with status (SYS_EXIT_EXTENDED, ADP_Stopped_ApplicationExit). */
__attribute__((noreturn)) void emu_sh_exit(uint32_t status);

/** SYS_OPEN: a handle >= 0, or -1. */
int32_t emu_sh_open(const char *path, uint32_t mode);
/** SYS_CLOSE: 0 on success. */
int32_t emu_sh_close(int32_t h);
/** SYS_SEEK to an absolute position: 0 on success. */
int32_t emu_sh_seek(int32_t h, uint32_t pos);
/** SYS_WRITE: true when all len bytes were written. */
bool emu_sh_write(int32_t h, const void *data, uint32_t len);
/** SYS_READ: the number of bytes read. */
uint32_t emu_sh_read(int32_t h, void *buf, uint32_t len);

/** A console line being built (no printf in the image). */
typedef struct {
  char buf[256];
  size_t n;
} emu_line_t;

void emu_line_str(emu_line_t *l, const char *s);
void emu_line_u32(emu_line_t *l, uint32_t v);
void emu_line_hex(emu_line_t *l, uint32_t v, unsigned digits); /**< "0x" and digits */
void emu_line_f64(emu_line_t *l, double v);
/** Write the line and a newline to the console. */
void emu_line_emit(emu_line_t *l);

#endif /* PMLSM_EMU_SEMIHOST_H */
