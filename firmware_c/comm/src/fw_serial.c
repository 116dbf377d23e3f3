/**
 * @file fw_serial.c
 * @brief Serial link: COBS, CRC-16/CCITT-FALSE, frames, telemetry, trace.
 */
#include "pmlsm/fw_serial.h"

#include <math.h>
#include <string.h>

/* ---- little endian helpers ---------------------------------------------- */

static void put_u16(uint8_t *p, uint16_t v) {
  p[0] = (uint8_t)v;
  p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v) {
  for (size_t i = 0u; i < 4u; i++) {
    p[i] = (uint8_t)(v >> (8u * i));
  }
}

static void put_f32(uint8_t *p, float f) {
  uint32_t v;
  memcpy(&v, &f, sizeof v);
  put_u32(p, v);
}

/* ---- CRC and COBS ---------------------------------------------------------- */

uint16_t fw_serial_crc16(const uint8_t *data, size_t len) {
  uint16_t crc = 0xFFFFu;
  if (data == NULL) {
    return crc;
  }
  /* CRC-16/CCITT-FALSE (poly 0x1021) a byte at a time without a table: the
     eight shift/xor steps of the bit-wise form folded into shifts of the
     byte's combined feedback x (the same value; test_serial compares both) */
  for (size_t i = 0u; i < len; i++) {
    uint32_t x = ((uint32_t)crc >> 8) ^ data[i];
    x ^= x >> 4;
    crc = (uint16_t)(((uint32_t)crc << 8) ^ (x << 12) ^ (x << 5) ^ x);
  }
  return crc;
}

size_t fw_serial_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap) {
  if ((in == NULL && len > 0u) || out == NULL || cap == 0u) {
    return 0u;
  }
  size_t code_pos = 0u;
  size_t o = 1u;
  uint8_t code = 1u;
  for (size_t i = 0u; i < len; i++) {
    if (in[i] == 0u) {
      out[code_pos] = code;
      code_pos = o;
      if (o >= cap) {
        return 0u;
      }
      o++;
      code = 1u;
    } else {
      if (o >= cap) {
        return 0u;
      }
      out[o++] = in[i];
      code++;
      if (code == 0xFFu) {
        out[code_pos] = code;
        if (i + 1u == len) {
          return o; /* a full block at the end needs no trailing code */
        }
        code_pos = o;
        if (o >= cap) {
          return 0u;
        }
        o++;
        code = 1u;
      }
    }
  }
  out[code_pos] = code;
  return o;
}

fw_serial_status_t fw_serial_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap,
                                         size_t *out_len) {
  if (in == NULL || out == NULL || out_len == NULL) {
    return FW_SERIAL_ERR_NULL;
  }
  size_t i = 0u;
  size_t o = 0u;
  *out_len = 0u;
  if (len == 0u) {
    return FW_SERIAL_ERR_COBS;
  }
  while (i < len) {
    uint8_t code = in[i++];
    if (code == 0u) {
      return FW_SERIAL_ERR_COBS;
    }
    for (uint8_t k = 1u; k < code; k++) {
      if (i >= len) {
        return FW_SERIAL_ERR_COBS; /* truncated block */
      }
      if (in[i] == 0u) {
        return FW_SERIAL_ERR_COBS;
      }
      if (o >= cap) {
        return FW_SERIAL_ERR_SPACE;
      }
      out[o++] = in[i++];
    }
    if (code != 0xFFu && i < len) {
      if (o >= cap) {
        return FW_SERIAL_ERR_SPACE;
      }
      out[o++] = 0u;
    }
  }
  *out_len = o;
  return FW_SERIAL_OK;
}

/* ---- frames -------------------------------------------------------------- */

fw_serial_status_t fw_serial_encode(uint8_t type, uint16_t seq, const uint8_t *payload,
                                    size_t len, uint8_t *out, size_t cap, size_t *out_len) {
  uint8_t raw[FW_SERIAL_MAX_RAW];
  if (out == NULL || out_len == NULL || (payload == NULL && len > 0u)) {
    return FW_SERIAL_ERR_NULL;
  }
  *out_len = 0u;
  if (len > FW_SERIAL_MAX_PAYLOAD) {
    return FW_SERIAL_ERR_ARG;
  }
  raw[0] = type;
  put_u16(&raw[1], seq);
  if (len > 0u) {
    memcpy(&raw[3], payload, len);
  }
  put_u16(&raw[3u + len], fw_serial_crc16(raw, 3u + len));
  if (cap < 2u) {
    return FW_SERIAL_ERR_SPACE;
  }
  size_t n = fw_serial_cobs_encode(raw, 5u + len, out, cap - 1u);
  if (n == 0u) {
    return FW_SERIAL_ERR_SPACE;
  }
  out[n] = 0u;
  *out_len = n + 1u;
  return FW_SERIAL_OK;
}

fw_serial_status_t fw_serial_decode(const uint8_t *frame, size_t len, fw_serial_msg_t *msg) {
  uint8_t raw[FW_SERIAL_MAX_RAW];
  size_t n = 0u;
  if (frame == NULL || msg == NULL) {
    return FW_SERIAL_ERR_NULL;
  }
  if (len > FW_SERIAL_MAX_ENCODED) {
    return FW_SERIAL_ERR_TOO_LONG;
  }
  fw_serial_status_t st = fw_serial_cobs_decode(frame, len, raw, sizeof raw, &n);
  if (st == FW_SERIAL_ERR_SPACE) {
    return FW_SERIAL_ERR_TOO_LONG;
  }
  if (st != FW_SERIAL_OK) {
    return st;
  }
  if (n < 5u) {
    return FW_SERIAL_ERR_SHORT;
  }
  uint16_t crc = (uint16_t)(raw[n - 2u] | (raw[n - 1u] << 8));
  if (fw_serial_crc16(raw, n - 2u) != crc) {
    return FW_SERIAL_ERR_CRC;
  }
  msg->type = raw[0];
  msg->seq = (uint16_t)(raw[1] | (raw[2] << 8));
  msg->len = (uint16_t)(n - 5u);
  memcpy(msg->payload, &raw[3], msg->len);
  return FW_SERIAL_OK;
}

void fw_serial_link_init(fw_serial_link_t *link) {
  if (link != NULL) {
    link->seq = 0u;
  }
}

fw_serial_status_t fw_serial_link_send(fw_serial_link_t *link, uint8_t type,
                                       const uint8_t *payload, size_t len, uint8_t *out,
                                       size_t cap, size_t *out_len) {
  if (link == NULL) {
    return FW_SERIAL_ERR_NULL;
  }
  fw_serial_status_t st = fw_serial_encode(type, link->seq, payload, len, out, cap, out_len);
  if (st == FW_SERIAL_OK) {
    link->seq = (uint16_t)(link->seq + 1u);
  }
  return st;
}

void fw_serial_decoder_init(fw_serial_decoder_t *dec) {
  if (dec != NULL) {
    memset(dec, 0, sizeof *dec);
  }
}

fw_serial_status_t fw_serial_decoder_push(fw_serial_decoder_t *dec, uint8_t byte,
                                          fw_serial_msg_t *msg) {
  if (dec == NULL || msg == NULL) {
    return FW_SERIAL_ERR_NULL;
  }
  if (byte != 0u) {
    if (dec->len >= sizeof dec->buf) {
      dec->overflow = 1u;
      dec->len = 0u;
    }
    if (!dec->overflow) {
      dec->buf[dec->len++] = byte;
    }
    return FW_SERIAL_INCOMPLETE;
  }
  if (dec->overflow) {
    dec->overflow = 0u;
    dec->len = 0u;
    dec->frames_bad++;
    return FW_SERIAL_ERR_TOO_LONG;
  }
  if (dec->len == 0u) {
    return FW_SERIAL_INCOMPLETE; /* idle delimiters */
  }
  fw_serial_status_t st = fw_serial_decode(dec->buf, dec->len, msg);
  dec->len = 0u;
  if (st != FW_SERIAL_OK) {
    dec->frames_bad++;
    return st;
  }
  if (dec->have_seq && msg->seq != dec->next_seq) {
    uint16_t gap = (uint16_t)(msg->seq - dec->next_seq);
    if (gap > FW_SERIAL_RESTART_GAP) {
      dec->restarts++; /* behind the expected number: the sender restarted */
    } else {
      dec->frames_lost += gap;
    }
  }
  dec->have_seq = 1u;
  dec->next_seq = (uint16_t)(msg->seq + 1u);
  dec->frames_ok++;
  return FW_SERIAL_OK;
}

/* ---- signals / telemetry ------------------------------------------------- */

float fw_serial_signal_value(const fw_snapshot_t *snap, uint8_t id) {
  if (snap == NULL || id >= FW_SERIAL_SIGNAL_COUNT) {
    return 0.0f;
  }
  const fw_serial_signal_t *s = &fw_serial_signals[id];
  const uint8_t *base = (const uint8_t *)snap;
  switch (s->type) {
  case FW_SIG_U8:
    return (float)base[s->offset];
  case FW_SIG_U16: {
    uint16_t v;
    memcpy(&v, base + s->offset, sizeof v);
    return (float)v;
  }
  default: {
    float f;
    memcpy(&f, base + s->offset, sizeof f);
    return f;
  }
  }
}

size_t fw_serial_telemetry_payload(const fw_snapshot_t *snap, const uint8_t *ids, uint8_t n,
                                   uint8_t *out, size_t cap) {
  if (snap == NULL || ids == NULL || out == NULL || n > FW_SERIAL_MAX_SIGNALS) {
    return 0u;
  }
  size_t need = 5u + (size_t)n * 5u;
  if (cap < need) {
    return 0u;
  }
  put_u32(out, snap->step_count);
  out[4] = n;
  for (uint8_t k = 0u; k < n; k++) {
    out[5u + k] = ids[k];
    put_f32(&out[5u + n + 4u * k], fw_serial_signal_value(snap, ids[k]));
  }
  return need;
}

/* ---- trace ------------------------------------------------------------------ */

fw_serial_status_t fw_trace_init(fw_trace_t *tr, float *storage, uint32_t capacity) {
  if (tr == NULL || storage == NULL) {
    return FW_SERIAL_ERR_NULL;
  }
  if (capacity == 0u) {
    return FW_SERIAL_ERR_ARG;
  }
  memset(tr, 0, sizeof *tr);
  tr->storage = storage;
  tr->capacity = capacity;
  tr->state = FW_TRACE_IDLE;
  return FW_SERIAL_OK;
}

fw_serial_status_t fw_trace_arm(fw_trace_t *tr, const uint8_t *ids, uint8_t n, uint32_t pre,
                                uint8_t trig_sig, float level, fw_trace_edge_t edge,
                                float dt_s) {
  if (tr == NULL || ids == NULL || tr->storage == NULL) {
    return FW_SERIAL_ERR_NULL;
  }
  if (n == 0u || n > FW_SERIAL_MAX_SIGNALS || trig_sig >= FW_SERIAL_SIGNAL_COUNT ||
      (uint32_t)edge > (uint32_t)FW_TRACE_ON_FAULT || !isfinite(level) || !isfinite(dt_s)) {
    return FW_SERIAL_ERR_ARG;
  }
  for (uint8_t k = 0u; k < n; k++) {
    if (ids[k] >= FW_SERIAL_SIGNAL_COUNT) {
      return FW_SERIAL_ERR_ARG;
    }
  }
  uint32_t depth = tr->capacity / n;
  if (depth < 2u || pre >= depth) {
    return FW_SERIAL_ERR_ARG;
  }
  tr->n_sig = n;
  memcpy(tr->ids, ids, n);
  tr->depth = depth;
  tr->pre = pre;
  tr->trig_sig = trig_sig;
  tr->edge = (uint8_t)edge;
  tr->level = level;
  tr->have_prev = 0u;
  tr->wr = 0u;
  tr->filled = 0u;
  tr->post_left = 0u;
  tr->dt_s = dt_s;
  tr->capture_id = (uint16_t)(tr->capture_id + 1u);
  tr->state = FW_TRACE_ARMED;
  return FW_SERIAL_OK;
}

void fw_trace_trigger(fw_trace_t *tr, uint32_t step) {
  if (tr == NULL || tr->state != FW_TRACE_ARMED) {
    return;
  }
  tr->state = FW_TRACE_TRIGGERED;
  tr->trigger_step = step;
  /* keep at most `pre` samples from before the trigger */
  uint32_t kept = tr->filled < tr->pre ? tr->filled : tr->pre;
  tr->filled = kept;
  tr->pre_kept = kept;
  tr->post_left = tr->depth - kept;
}

void fw_trace_stop(fw_trace_t *tr) {
  if (tr != NULL) {
    tr->state = FW_TRACE_IDLE;
  }
}

void fw_trace_sample(fw_trace_t *tr, const fw_snapshot_t *snap, bool fault) {
  if (tr == NULL || snap == NULL || tr->storage == NULL || tr->n_sig == 0u) {
    return;
  }
  if (tr->state == FW_TRACE_ARMED) {
    float v = fw_serial_signal_value(snap, tr->trig_sig);
    bool fire = false;
    if (tr->edge == FW_TRACE_ON_FAULT) {
      fire = fault;
    } else if (tr->have_prev) {
      bool up = tr->prev < tr->level && v >= tr->level;
      bool down = tr->prev > tr->level && v <= tr->level;
      fire = (tr->edge == FW_TRACE_EDGE_RISING && up) ||
             (tr->edge == FW_TRACE_EDGE_FALLING && down) ||
             (tr->edge == FW_TRACE_EDGE_EITHER && (up || down));
    }
    tr->prev = v;
    tr->have_prev = 1u;
    if (fire) {
      fw_trace_trigger(tr, snap->step_count);
    }
  }
  if (tr->state != FW_TRACE_ARMED && tr->state != FW_TRACE_TRIGGERED) {
    return;
  }
  float *row = &tr->storage[(size_t)tr->wr * tr->n_sig];
  for (uint8_t k = 0u; k < tr->n_sig; k++) {
    row[k] = fw_serial_signal_value(snap, tr->ids[k]);
  }
  tr->wr = (tr->wr + 1u) % tr->depth;
  if (tr->state == FW_TRACE_ARMED) {
    if (tr->filled < tr->depth) {
      tr->filled++;
    }
    return;
  }
  tr->filled++;
  tr->post_left--;
  if (tr->post_left == 0u) {
    tr->state = FW_TRACE_DONE;
    tr->start = (tr->wr + tr->depth - tr->filled) % tr->depth;
  }
}

fw_serial_status_t fw_trace_upload_start(fw_trace_t *tr) {
  if (tr == NULL) {
    return FW_SERIAL_ERR_NULL;
  }
  if (tr->state != FW_TRACE_DONE && tr->state != FW_TRACE_UPLOADING) {
    return FW_SERIAL_ERR_ARG;
  }
  tr->state = FW_TRACE_UPLOADING;
  tr->up_next = 0u;
  tr->up_stage = 0u;
  return FW_SERIAL_OK;
}

bool fw_trace_upload_next(fw_trace_t *tr, uint8_t *type, uint8_t *payload, size_t cap,
                          size_t *len) {
  if (tr == NULL || type == NULL || payload == NULL || len == NULL ||
      tr->state != FW_TRACE_UPLOADING || cap < 32u) {
    return false;
  }
  uint8_t n = tr->n_sig;
  if (tr->up_stage == 0u) {
    /* header: id u16 | n u8 | ids[n] | samples u32 | pre u32 | trigger_step u32 | dt f32 */
    size_t o = 0u;
    put_u16(&payload[o], tr->capture_id);
    o += 2u;
    payload[o++] = n;
    memcpy(&payload[o], tr->ids, n);
    o += n;
    put_u32(&payload[o], tr->filled);
    o += 4u;
    put_u32(&payload[o], tr->pre_kept);
    o += 4u;
    put_u32(&payload[o], tr->trigger_step);
    o += 4u;
    put_f32(&payload[o], tr->dt_s);
    o += 4u;
    *type = FW_SERIAL_TYPE_TRACE_HEADER;
    *len = o;
    tr->up_stage = 1u;
    return true;
  }
  if (tr->up_stage == 1u && tr->up_next < tr->filled) {
    /* data: id u16 | first u32 | count u8 | count x n x f32 (sample major) */
    size_t per = (size_t)n * 4u;
    size_t room = (cap < FW_SERIAL_MAX_PAYLOAD ? cap : FW_SERIAL_MAX_PAYLOAD) - 7u;
    uint32_t count = (uint32_t)(room / per);
    uint32_t left = tr->filled - tr->up_next;
    if (count > left) {
      count = left;
    }
    if (count > 255u) {
      count = 255u;
    }
    if (count == 0u) {
      return false;
    }
    put_u16(&payload[0], tr->capture_id);
    put_u32(&payload[2], tr->up_next);
    payload[6] = (uint8_t)count;
    size_t o = 7u;
    for (uint32_t s = 0u; s < count; s++) {
      uint32_t ring = (tr->start + tr->up_next + s) % tr->depth;
      for (uint8_t k = 0u; k < n; k++) {
        put_f32(&payload[o], tr->storage[(size_t)ring * n + k]);
        o += 4u;
      }
    }
    tr->up_next += count;
    *type = FW_SERIAL_TYPE_TRACE_DATA;
    *len = o;
    return true;
  }
  /* end: id u16 | samples u32 */
  put_u16(&payload[0], tr->capture_id);
  put_u32(&payload[2], tr->filled);
  *type = FW_SERIAL_TYPE_TRACE_END;
  *len = 6u;
  tr->state = FW_TRACE_DONE;
  tr->up_stage = 0u;
  return true;
}
