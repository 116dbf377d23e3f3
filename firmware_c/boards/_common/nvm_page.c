/**
 * @file nvm_page.c
 * @brief Parameter block in one flash page (nvm_page.h).
 */
#include "nvm_page.h"

#include <string.h>

#define NVM_UNIT_MAX 32u /* largest program unit supported */

static uint32_t le32(const uint8_t *p) {
  return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static void put_le32(uint8_t *p, uint32_t v) {
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
  p[2] = (uint8_t)(v >> 16);
  p[3] = (uint8_t)(v >> 24);
}

static bool geometry_ok(const nvm_page_t *m) {
  return m != NULL && m->erase != NULL && m->program != NULL && m->view != NULL &&
         m->prog_unit >= 8u && m->prog_unit <= NVM_UNIT_MAX && m->page_size > m->prog_unit &&
         m->page_size % m->prog_unit == 0u;
}

fw_nvm_status_t nvm_page_read(const nvm_page_t *m, uint8_t *buf, size_t cap, size_t *len) {
  if (len != NULL) {
    *len = 0u;
  }
  if (!geometry_ok(m) || buf == NULL || len == NULL) {
    return FW_NVM_ERROR;
  }
  const uint8_t *page = m->view(m->ctx);
  if (page == NULL) {
    return FW_NVM_ERROR;
  }
  const uint32_t n = le32(page), check = le32(page + 4);
  if (n == 0xFFFFFFFFu && check == 0xFFFFFFFFu) {
    return FW_NVM_EMPTY; /* erased, or a write that never reached its header */
  }
  if (check != ~n || n == 0u || n > nvm_page_capacity(m)) {
    /* a header torn in its own program operation: hand over one byte, which no
       block's CRC passes (the application boots on its defaults) */
    if (cap == 0u) {
      return FW_NVM_ERROR;
    }
    buf[0] = page[0];
    *len = 1u;
    return FW_NVM_OK;
  }
  if (n > cap) {
    return FW_NVM_ERROR; /* the block does not fit the caller's buffer */
  }
  memcpy(buf, page + m->prog_unit, n);
  *len = n;
  return FW_NVM_OK;
}

fw_nvm_status_t nvm_page_write(const nvm_page_t *m, const uint8_t *data, size_t len) {
  if (!geometry_ok(m) || (data == NULL && len > 0u)) {
    return FW_NVM_ERROR;
  }
  if (len > nvm_page_capacity(m)) {
    return FW_NVM_ERROR;
  }
  if (!m->erase(m->ctx)) {
    return FW_NVM_ERROR;
  }
  if (len == 0u) {
    return FW_NVM_OK; /* erased: FW_NVM_EMPTY from now on */
  }
  const uint32_t u = m->prog_unit;
  uint8_t unit[NVM_UNIT_MAX];
  /* the block, whole units first, then the last partial unit padded with 0xFF */
  const uint32_t whole = (uint32_t)len / u * u;
  if (whole > 0u && !m->program(m->ctx, u, data, whole)) {
    return FW_NVM_ERROR;
  }
  if (whole < len) {
    memset(unit, 0xFF, sizeof unit);
    memcpy(unit, data + whole, len - whole);
    if (!m->program(m->ctx, u + whole, unit, u)) {
      return FW_NVM_ERROR;
    }
  }
  /* the header last: until it is there, the page reads as erased */
  memset(unit, 0xFF, sizeof unit);
  put_le32(unit, (uint32_t)len);
  put_le32(unit + 4, ~(uint32_t)len);
  if (!m->program(m->ctx, 0u, unit, u)) {
    return FW_NVM_ERROR;
  }
  /* verify what the medium holds */
  const uint8_t *page = m->view(m->ctx);
  if (page == NULL || le32(page) != (uint32_t)len || memcmp(page + u, data, len) != 0) {
    return FW_NVM_ERROR;
  }
  return FW_NVM_OK;
}
