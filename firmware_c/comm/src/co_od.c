/**
 * @file co_od.c
 * @brief Object dictionary access: lookup, defaults, checks, typed access.
 */
#include "pmlsm/co_od.h"

#include <math.h>
#include <string.h>

#include "co_od_table.h"

uint32_t co_le_get(const uint8_t *p, size_t n) {
  return (p == NULL || n > 4u) ? 0u : co_le_load(p, n);
}

void co_le_put(uint8_t *p, size_t n, uint32_t v) {
  if (p != NULL && n <= 4u) {
    co_le_store(p, n, v);
  }
}

uint16_t co_od_count(void) { return (uint16_t)CO_OD_COUNT; }

const co_od_entry_t *co_od_entry(uint16_t pos) {
  return pos < CO_OD_COUNT ? &co_od_table[pos] : NULL;
}

size_t co_od_ram_size(void) { return (size_t)CO_OD_RAM_SIZE; }

co_od_status_t co_od_find(uint16_t index, uint8_t sub, uint16_t *pos) {
  uint32_t key = ((uint32_t)index << 8) | sub;
  uint32_t lo = 0u;
  uint32_t hi = CO_OD_COUNT;
  bool index_seen = false;
  while (lo < hi) {
    uint32_t mid = lo + (hi - lo) / 2u;
    const co_od_entry_t *e = &co_od_table[mid];
    uint32_t k = ((uint32_t)e->index << 8) | e->sub;
    if (e->index == index) {
      index_seen = true;
    }
    if (k == key) {
      if (pos != NULL) {
        *pos = (uint16_t)mid;
      }
      return CO_OD_OK;
    }
    if (k < key) {
      lo = mid + 1u;
    } else {
      hi = mid;
    }
  }
  if (!index_seen) {
    /* The binary search may have skipped the index's other subs. */
    if (lo < CO_OD_COUNT && co_od_table[lo].index == index) {
      index_seen = true;
    }
    if (lo > 0u && co_od_table[lo - 1u].index == index) {
      index_seen = true;
    }
  }
  return index_seen ? CO_OD_NO_SUB : CO_OD_NO_OBJECT;
}

static bool co_od_in_ram(const co_od_entry_t *e, size_t ram_size) {
  if (ram_size >= CO_OD_RAM_SIZE) {
    return true; /* every generated entry lies inside CO_OD_RAM_SIZE (test_co_od_config) */
  }
  size_t need = (size_t)e->offset + e->size + (e->type == CO_TYPE_VSTRING ? 1u : 0u);
  return need <= ram_size;
}

static int64_t co_od_decode_int(const co_od_entry_t *e, const uint8_t *data) {
  uint32_t raw = co_le_load(data, e->size);
  switch (e->type) {
  case CO_TYPE_I8:
    return (int64_t)(int8_t)(uint8_t)raw;
  case CO_TYPE_I16:
    return (int64_t)(int16_t)(uint16_t)raw;
  case CO_TYPE_I32:
    return (int64_t)(int32_t)raw;
  default:
    return (int64_t)raw;
  }
}

co_abort_t co_od_check(uint16_t pos, const uint8_t *data, size_t len) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (e == NULL || (data == NULL && len > 0u)) {
    return CO_ABORT_GENERAL;
  }
  if (e->type == CO_TYPE_VSTRING) {
    return len <= e->size ? CO_ABORT_NONE : CO_ABORT_TYPE_LEN;
  }
  if (len != e->size) {
    return CO_ABORT_TYPE_LEN;
  }
  if (e->type == CO_TYPE_REAL32) {
    const float f = co_le_load_f32(data); /* len == 4 here: data is not NULL */
    if (!isfinite(f)) {
      return CO_ABORT_VALUE_RANGE;
    }
    if (f > e->max_f) {
      return CO_ABORT_VALUE_HIGH;
    }
    if (f < e->min_f) {
      return CO_ABORT_VALUE_LOW;
    }
    return CO_ABORT_NONE;
  }
  int64_t v = co_od_decode_int(e, data);
  if (v > e->max_i) {
    return CO_ABORT_VALUE_HIGH;
  }
  if (v < e->min_i) {
    return CO_ABORT_VALUE_LOW;
  }
  return CO_ABORT_NONE;
}

void co_od_store(uint8_t *ram, size_t ram_size, uint16_t pos, const uint8_t *data,
                 size_t len) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (ram == NULL || e == NULL || (data == NULL && len > 0u) || !co_od_in_ram(e, ram_size)) {
    return;
  }
  if (e->type == CO_TYPE_VSTRING) {
    size_t n = len < e->size ? len : e->size;
    /* a trailing NUL written by a client is not part of the string */
    while (n > 0u && data[n - 1u] == 0u) {
      n--;
    }
    ram[e->offset] = (uint8_t)n;
    if (n > 0u) {
      memcpy(&ram[e->offset + 1u], data, n);
    }
    return;
  }
  if (len != e->size) {
    return;
  }
  memcpy(&ram[e->offset], data, len);
}

size_t co_od_load(const uint8_t *ram, size_t ram_size, uint16_t pos, uint8_t *buf,
                  size_t cap) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (ram == NULL || buf == NULL || e == NULL || !co_od_in_ram(e, ram_size)) {
    return 0u;
  }
  if (e->type == CO_TYPE_VSTRING) {
    size_t n = ram[e->offset];
    if (n > e->size) {
      n = e->size;
    }
    if (n > cap) {
      return 0u;
    }
    memcpy(buf, &ram[e->offset + 1u], n);
    return n;
  }
  if (e->size > cap) {
    return 0u;
  }
  memcpy(buf, &ram[e->offset], e->size);
  return e->size;
}

void co_od_reset(uint8_t *ram, size_t ram_size, uint8_t node_id) {
  if (ram == NULL) {
    return;
  }
  for (uint16_t pos = 0u; pos < CO_OD_COUNT; pos++) {
    const co_od_entry_t *e = &co_od_table[pos];
    /* 8, not 4: GCC's -O3 LTO build (the simulator library) unrolls
       co_le_put past its n <= 4 guard and warns (-Wstringop-overflow) */
    uint8_t buf[8];
    if (!co_od_in_ram(e, ram_size)) {
      continue;
    }
    if (e->type == CO_TYPE_VSTRING) {
      size_t n = e->def_s != NULL ? strlen(e->def_s) : 0u;
      co_od_store(ram, ram_size, pos, (const uint8_t *)e->def_s, n);
    } else if (e->type == CO_TYPE_REAL32) {
      co_le_store_f32(buf, e->def_f);
      co_od_store(ram, ram_size, pos, buf, 4u);
    } else {
      int64_t v = e->def_i;
      if ((e->flags & CO_FLAG_NODEID) != 0u) {
        v += node_id;
      }
      co_le_put(buf, e->size, (uint32_t)(uint64_t)v);
      co_od_store(ram, ram_size, pos, buf, e->size);
    }
  }
}

uint32_t co_od_get_u32(const uint8_t *ram, size_t ram_size, uint16_t pos) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (ram == NULL || e == NULL || e->size > 4u || e->type == CO_TYPE_VSTRING ||
      !co_od_in_ram(e, ram_size)) {
    return 0u;
  }
  return co_le_load(&ram[e->offset], e->size);
}

int32_t co_od_get_i32(const uint8_t *ram, size_t ram_size, uint16_t pos) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (ram == NULL || e == NULL || e->size > 4u || e->type == CO_TYPE_VSTRING ||
      !co_od_in_ram(e, ram_size)) {
    return 0;
  }
  return (int32_t)co_od_decode_int(e, &ram[e->offset]);
}

float co_od_get_f32(const uint8_t *ram, size_t ram_size, uint16_t pos) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (ram == NULL || e == NULL || e->type != CO_TYPE_REAL32 || !co_od_in_ram(e, ram_size)) {
    return 0.0f;
  }
  return co_le_load_f32(&ram[e->offset]);
}

void co_od_set_u32(uint8_t *ram, size_t ram_size, uint16_t pos, uint32_t v) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (ram == NULL || e == NULL || e->size > 4u || e->type == CO_TYPE_VSTRING ||
      e->type == CO_TYPE_REAL32 || !co_od_in_ram(e, ram_size)) {
    return;
  }
  co_le_store(&ram[e->offset], e->size, v);
}

void co_od_set_i32(uint8_t *ram, size_t ram_size, uint16_t pos, int32_t v) {
  co_od_set_u32(ram, ram_size, pos, (uint32_t)v);
}

void co_od_set_f32(uint8_t *ram, size_t ram_size, uint16_t pos, float v) {
  const co_od_entry_t *e = co_od_entry(pos);
  if (ram == NULL || e == NULL || e->type != CO_TYPE_REAL32 || !co_od_in_ram(e, ram_size)) {
    return;
  }
  co_le_store_f32(&ram[e->offset], v);
}
