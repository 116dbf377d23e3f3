/**
 * @file co_od.h
 * @brief Object dictionary access for the CANopen slave.
 *
 * The table itself (co_od_table[], CO_OD_COUNT, CO_OD_RAM_SIZE and one
 * CO_OD_iiii_ss position constant per entry) is generated from
 * protocols/od.yaml by protocols/generate.py into
 * firmware_c/comm/generated/co_od_table.c/.h. The table is const; the
 * values live in a caller-owned byte array ("OD RAM", little endian, the
 * CAN byte order) inside co_node_t. Strings are stored as one length byte
 * followed by `size` characters.
 */
#ifndef PMLSM_CO_OD_H
#define PMLSM_CO_OD_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#ifdef __cplusplus
extern "C" {
#endif

/** CiA 301 basic data types (values are the CiA 301 data type codes). */
typedef enum {
  CO_TYPE_BOOLEAN = 0x01,
  CO_TYPE_I8 = 0x02,
  CO_TYPE_I16 = 0x03,
  CO_TYPE_I32 = 0x04,
  CO_TYPE_U8 = 0x05,
  CO_TYPE_U16 = 0x06,
  CO_TYPE_U32 = 0x07,
  CO_TYPE_REAL32 = 0x08,
  CO_TYPE_VSTRING = 0x09
} co_type_t;

/** Access bits of an entry. */
#define CO_ACC_R 0x01u     /**< readable by SDO */
#define CO_ACC_W 0x02u     /**< writable by SDO */
#define CO_ACC_CONST 0x04u /**< constant (also readable) */

/** Flag bits of an entry. */
#define CO_FLAG_PDO 0x01u    /**< PDO mappable */
#define CO_FLAG_NODEID 0x02u /**< default is node id + def_i */
#define CO_FLAG_CMD 0x04u    /**< an action or set-point, not configuration (od.yaml `command`) */

/* SDO abort codes (CiA 301): co_abort_t, generated from protocols/od.yaml (sdo_aborts:). */
#include "co_aborts.h"

/** One object dictionary entry (generated). */
typedef struct {
  uint16_t index;
  uint8_t sub;
  uint8_t type;   /**< co_type_t */
  uint8_t access; /**< CO_ACC_* */
  uint8_t flags;  /**< CO_FLAG_* */
  uint16_t size;  /**< bytes; maximum length for strings */
  uint16_t offset; /**< into the OD RAM */
  int64_t min_i, max_i, def_i; /**< integer types: inclusive limits, default */
  float min_f, max_f, def_f;   /**< REAL32: inclusive limits, default */
  const char *def_s;           /**< VISIBLE_STRING default */
  const char *name;
} co_od_entry_t;

/** An entry that mirrors a fw_config_t field (generated). */
typedef struct {
  uint16_t pos;      /**< table position */
  const char *field; /**< fw_config_t field name */
  float scale;       /**< integer entries: wire value = field value x scale
                          (e.g. 1e6 for m/s shown in um/s); 1 otherwise */
} co_od_cfg_link_t;

/** Result of a lookup. */
typedef enum {
  CO_OD_OK = 0,
  CO_OD_NO_OBJECT = 1, /**< no entry with this index */
  CO_OD_NO_SUB = 2     /**< index exists, sub-index does not */
} co_od_status_t;

/** Number of entries in the generated table. */
uint16_t co_od_count(void);
/** Entry at table position pos (NULL when out of range). */
const co_od_entry_t *co_od_entry(uint16_t pos);
/** Binary search; *pos is the table position on CO_OD_OK. */
co_od_status_t co_od_find(uint16_t index, uint8_t sub, uint16_t *pos);

/** Size of the OD RAM in bytes (CO_OD_RAM_SIZE). */
size_t co_od_ram_size(void);
/** Write every default (node-id relative ones with node_id added). */
void co_od_reset(uint8_t *ram, size_t ram_size, uint8_t node_id);

/**
 * Check a value for entry pos without storing it: length (strings: up to
 * size), NaN/inf, limits. Returns CO_ABORT_NONE or the abort code.
 */
co_abort_t co_od_check(uint16_t pos, const uint8_t *data, size_t len);

/** Store a checked value (no checks beyond bounds). */
void co_od_store(uint8_t *ram, size_t ram_size, uint16_t pos, const uint8_t *data,
                 size_t len);
/**
 * Copy the value of entry pos to buf (little endian). Returns the number of
 * bytes (the string length for strings), 0 on a bad argument.
 */
size_t co_od_load(const uint8_t *ram, size_t ram_size, uint16_t pos, uint8_t *buf,
                  size_t cap);

/* Typed accessors (pos must be an entry of a matching size; 0 otherwise). */
uint32_t co_od_get_u32(const uint8_t *ram, size_t ram_size, uint16_t pos);
int32_t co_od_get_i32(const uint8_t *ram, size_t ram_size, uint16_t pos);
float co_od_get_f32(const uint8_t *ram, size_t ram_size, uint16_t pos);
void co_od_set_u32(uint8_t *ram, size_t ram_size, uint16_t pos, uint32_t v);
void co_od_set_i32(uint8_t *ram, size_t ram_size, uint16_t pos, int32_t v);
void co_od_set_f32(uint8_t *ram, size_t ram_size, uint16_t pos, float v);

/** Read a little-endian unsigned integer of n (1..4) bytes (0 for NULL or n > 4). */
uint32_t co_le_get(const uint8_t *p, size_t n);
/** Write v as n (1..4) little-endian bytes (nothing for NULL or n > 4). */
void co_le_put(uint8_t *p, size_t n, uint32_t v);

/* Little-endian access without the argument checks, for the per-period paths
 * (p valid, n 1..4; n > 4 reads 0 / writes nothing). On a little-endian
 * target (the compiler says so) 2 and 4 bytes are one memcpy, i.e. one
 * (unaligned) load or store on the Cortex-M4; elsewhere byte by byte. Both
 * give the same bytes (tests/c/test_co_od_config.c compares them). */
#if defined(__BYTE_ORDER__) && defined(__ORDER_LITTLE_ENDIAN__) && \
    __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
#define CO_LE_HOST 1
#else
#define CO_LE_HOST 0
#endif

static inline uint32_t co_le_load(const uint8_t *p, size_t n) {
  if (n == 1u) {
    return p[0];
  }
#if CO_LE_HOST
  if (n == 4u) {
    uint32_t v;
    memcpy(&v, p, sizeof v);
    return v;
  }
  if (n == 2u) {
    uint16_t v;
    memcpy(&v, p, sizeof v);
    return v;
  }
#endif
  uint32_t v = 0u;
  for (size_t i = 0u; i < n && i < 4u; i++) {
    v |= (uint32_t)p[i] << (8u * i);
  }
  return v;
}

static inline void co_le_store(uint8_t *p, size_t n, uint32_t v) {
  if (n == 1u) {
    p[0] = (uint8_t)v;
    return;
  }
  if (n > 4u) {
    return;
  }
#if CO_LE_HOST
  if (n == 4u) {
    memcpy(p, &v, sizeof v);
    return;
  }
  if (n == 2u) {
    uint16_t h = (uint16_t)v;
    memcpy(p, &h, sizeof h);
    return;
  }
#endif
  for (size_t i = 0u; i < n; i++) {
    p[i] = (uint8_t)(v >> (8u * i));
  }
}

/** A REAL32 as its 4 little-endian bytes (IEEE 754 bits, as on the wire). */
static inline float co_le_load_f32(const uint8_t *p) {
  const uint32_t raw = co_le_load(p, 4u);
  float f;
  memcpy(&f, &raw, sizeof f);
  return f;
}

static inline void co_le_store_f32(uint8_t *p, float v) {
  uint32_t raw;
  memcpy(&raw, &v, sizeof raw);
  co_le_store(p, 4u, raw);
}

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_CO_OD_H */
