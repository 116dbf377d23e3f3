/**
 * @file emu_semihost.c
 * @brief Semihosting calls and console lines (emu_semihost.h).
 */
#include "emu_semihost.h"

#include <string.h>

#include "sim_vmotor_link.h"

#define SYS_OPEN 0x01u
#define SYS_CLOSE 0x02u
#define SYS_WRITE0 0x04u
#define SYS_WRITE 0x05u
#define SYS_READ 0x06u
#define SYS_SEEK 0x0Au
#define SYS_EXIT_EXTENDED 0x20u
#define ADP_STOPPED_APPLICATION_EXIT 0x20026u

static uint32_t sh_call(uint32_t op, const void *arg) {
  register uint32_t r0 __asm("r0") = op;
  register const void *r1 __asm("r1") = arg;
  __asm volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
  return r0;
}

void emu_sh_write0(const char *s) {
  (void)sh_call(SYS_WRITE0, s);
}

void emu_sh_exit(uint32_t status) {
  const uint32_t block[2] = {ADP_STOPPED_APPLICATION_EXIT, status};
  (void)sh_call(SYS_EXIT_EXTENDED, block);
  for (;;) { /* not reached under QEMU */
    __asm volatile("wfi");
  }
}

int32_t emu_sh_open(const char *path, uint32_t mode) {
  const uint32_t block[3] = {(uint32_t)(uintptr_t)path, mode, (uint32_t)strlen(path)};
  return (int32_t)sh_call(SYS_OPEN, block);
}

int32_t emu_sh_close(int32_t h) {
  const uint32_t block[1] = {(uint32_t)h};
  return (int32_t)sh_call(SYS_CLOSE, block);
}

int32_t emu_sh_seek(int32_t h, uint32_t pos) {
  const uint32_t block[2] = {(uint32_t)h, pos};
  return (int32_t)sh_call(SYS_SEEK, block);
}

bool emu_sh_write(int32_t h, const void *data, uint32_t len) {
  const uint32_t block[3] = {(uint32_t)h, (uint32_t)(uintptr_t)data, len};
  return sh_call(SYS_WRITE, block) == 0u; /* bytes not written */
}

uint32_t emu_sh_read(int32_t h, void *buf, uint32_t len) {
  const uint32_t block[3] = {(uint32_t)h, (uint32_t)(uintptr_t)buf, len};
  const uint32_t left = sh_call(SYS_READ, block); /* bytes not read */
  return left <= len ? len - left : 0u;
}

/* ---- console lines ------------------------------------------------------------ */

void emu_line_str(emu_line_t *l, const char *s) {
  while (*s != '\0' && l->n + 2u < sizeof l->buf) {
    l->buf[l->n++] = *s++;
  }
}

void emu_line_u32(emu_line_t *l, uint32_t v) {
  char d[11];
  size_t n = 0u;
  do {
    d[n++] = (char)('0' + (int)(v % 10u));
    v /= 10u;
  } while (v != 0u);
  char s[12];
  for (size_t k = 0u; k < n; k++) {
    s[k] = d[n - 1u - k];
  }
  s[n] = '\0';
  emu_line_str(l, s);
}

void emu_line_hex(emu_line_t *l, uint32_t v, unsigned digits) {
  static const char HEX[] = "0123456789ABCDEF";
  char s[11];
  size_t n = 0u;
  s[n++] = '0';
  s[n++] = 'x';
  if (digits > 8u) {
    digits = 8u;
  }
  for (unsigned k = digits; k > 0u; k--) {
    s[n++] = HEX[(v >> (4u * (k - 1u))) & 0xFu];
  }
  s[n] = '\0';
  emu_line_str(l, s);
}

void emu_line_f64(emu_line_t *l, double v) {
  char s[40];
  if (sim_vmotor_format_f64(s, sizeof s, v) > 0u) {
    emu_line_str(l, s);
  }
}

void emu_line_emit(emu_line_t *l) {
  l->buf[l->n++] = '\n';
  l->buf[l->n] = '\0';
  emu_sh_write0(l->buf);
  l->n = 0u;
}
