/**
 * @file fuzz_slcan.c
 * @brief libFuzzer harness for the serial-line CAN endpoint
 *        (firmware_c/boards/_common/slcan.c): the input as the byte stream a
 *        host writes. Every CR gets exactly one reply and no other byte
 *        does; a reply fits SLCAN_REPLY_MAX; a frame handed to the drive is
 *        an 11-bit frame that the encoder writes as a line which a second
 *        endpoint parses back to the same frame; the line buffer never
 *        exceeds its bound; the counters add up to the lines seen.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "slcan.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void roundtrip(const fw_can_frame_t *f, uint32_t stamp) {
  slcan_t enc, dec;
  slcan_init(&enc, NULL, NULL);
  slcan_init(&dec, NULL, NULL);
  if ((stamp & 1u) != 0u) {
    slcan_reply_t r;
    fw_can_frame_t g;
    (void)slcan_push(&enc, 'Z', &g, &r);
    (void)slcan_push(&enc, '1', &g, &r);
    (void)slcan_push(&enc, '\r', &g, &r); /* time stamps on: the decoder must refuse them */
  }
  char line[SLCAN_FRAME_MAX];
  size_t n = slcan_encode(&enc, f, stamp, line, sizeof line);
  if (n == 0u || n > SLCAN_FRAME_MAX || line[n - 1u] != '\r') {
    abort();
  }
  slcan_reply_t r;
  fw_can_frame_t back;
  (void)slcan_push(&dec, 'O', &back, &r);
  (void)slcan_push(&dec, '\r', &back, &r);
  slcan_event_t ev = SLCAN_MORE;
  for (size_t i = 0u; i < n; i++) {
    ev = slcan_push(&dec, (uint8_t)line[i], &back, &r);
  }
  if (enc.timestamps) {
    /* a host line with a time stamp is not a valid frame line */
    if (ev != SLCAN_REPLY || r.len != 1u || r.text[0] != '\a') {
      abort();
    }
    return;
  }
  if (ev != SLCAN_FRAME || back.id != f->id || back.dlc != f->dlc || back.rtr != f->rtr ||
      (!f->rtr && memcmp(back.data, f->data, f->dlc) != 0)) {
    abort();
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  slcan_t s;
  slcan_init(&s, "0103", "E386");
  uint32_t crs = 0u, frames = 0u;
  for (size_t i = 0; i < size; i++) {
    fw_can_frame_t f;
    slcan_reply_t r;
    memset(&r, 0xA5, sizeof r);
    const slcan_event_t ev = slcan_push(&s, data[i], &f, &r);
    if (data[i] == '\r') {
      crs++;
      if (ev == SLCAN_MORE || r.len == 0u || r.len > SLCAN_REPLY_MAX) {
        abort();
      }
      const char last = r.text[r.len - 1u];
      if (last != '\r' && last != '\a') {
        abort();
      }
    } else if (ev != SLCAN_MORE || r.len != 0u) {
      abort();
    }
    if (ev == SLCAN_FRAME) {
      frames++;
      if (f.id > 0x7FFu || f.dlc > 8u || f.rtr > 1u || s.channel != (uint8_t)SLCAN_OPEN) {
        abort();
      }
      roundtrip(&f, (uint32_t)i * 7919u);
    }
    if (s.len > SLCAN_LINE_MAX) {
      abort();
    }
  }
  const slcan_counters_t *c = slcan_counters(&s);
  if (c->lines_ok + c->lines_bad != crs || c->frames_in != frames) {
    abort();
  }
  return 0;
}
