/**
 * @file byte_ring.h
 * @brief A single-producer single-consumer byte ring between an interrupt and
 *        the background (UART receive and transmit buffers of the board
 *        ports). Capacity a power of two; head written by the producer only,
 *        tail by the consumer only, each published with a release store.
 */
#ifndef PMLSM_BOARD_BYTE_RING_H
#define PMLSM_BOARD_BYTE_RING_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

typedef struct {
  uint8_t *buf;
  uint32_t mask; /**< capacity - 1 */
  _Atomic uint32_t head;
  _Atomic uint32_t tail;
  uint32_t dropped; /**< bytes the producer could not put (ring full) */
} byte_ring_t;

/** cap must be a power of two. */
static inline void byte_ring_init(byte_ring_t *r, uint8_t *buf, uint32_t cap) {
  r->buf = buf;
  r->mask = cap - 1u;
  atomic_store_explicit(&r->head, 0u, memory_order_relaxed);
  atomic_store_explicit(&r->tail, 0u, memory_order_relaxed);
  r->dropped = 0u;
}

static inline uint32_t byte_ring_used(byte_ring_t *r) {
  return atomic_load_explicit(&r->head, memory_order_acquire) -
         atomic_load_explicit(&r->tail, memory_order_acquire);
}

/** Producer: one byte; false (and counted) when full. */
static inline bool byte_ring_put(byte_ring_t *r, uint8_t b) {
  const uint32_t h = atomic_load_explicit(&r->head, memory_order_relaxed);
  if (h - atomic_load_explicit(&r->tail, memory_order_acquire) > r->mask) {
    r->dropped++;
    return false;
  }
  r->buf[h & r->mask] = b;
  atomic_store_explicit(&r->head, h + 1u, memory_order_release);
  return true;
}

/** Producer: up to len bytes; returns how many were taken. */
static inline size_t byte_ring_write(byte_ring_t *r, const uint8_t *data, size_t len) {
  const uint32_t h = atomic_load_explicit(&r->head, memory_order_relaxed);
  const uint32_t room = r->mask + 1u - (h - atomic_load_explicit(&r->tail, memory_order_acquire));
  const size_t n = len < room ? len : room;
  for (size_t i = 0u; i < n; i++) {
    r->buf[(h + (uint32_t)i) & r->mask] = data[i];
  }
  atomic_store_explicit(&r->head, h + (uint32_t)n, memory_order_release);
  return n;
}

/** Consumer: one byte into *b; false when empty. */
static inline bool byte_ring_get(byte_ring_t *r, uint8_t *b) {
  const uint32_t t = atomic_load_explicit(&r->tail, memory_order_relaxed);
  if (atomic_load_explicit(&r->head, memory_order_acquire) == t) {
    return false;
  }
  *b = r->buf[t & r->mask];
  atomic_store_explicit(&r->tail, t + 1u, memory_order_release);
  return true;
}

#endif /* PMLSM_BOARD_BYTE_RING_H */
