/**
 * @file fuzz_serial.c
 * @brief libFuzzer harness for the serial frame parser: the input as a byte
 *        stream into the decoder, and as one frame into fw_serial_decode.
 *        Every accepted frame must re-encode and decode to itself and move the
 *        loss/restart counters as its sequence gap says; the counters add up to
 *        the statuses returned; COBS decode(encode(x)) == x for arbitrary x.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "pmlsm/fw_serial.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void roundtrip(const fw_serial_msg_t *m) {
  uint8_t wire[FW_SERIAL_MAX_ENCODED];
  size_t n = 0;
  fw_serial_msg_t back;
  if (fw_serial_encode(m->type, m->seq, m->payload, m->len, wire, sizeof wire, &n) !=
          FW_SERIAL_OK ||
      fw_serial_decode(wire, n - 1u, &back) != FW_SERIAL_OK || back.len != m->len ||
      back.seq != m->seq || back.type != m->type ||
      memcmp(back.payload, m->payload, m->len) != 0) {
    abort();
  }
}

/* Trace capture with fuzzed configuration and samples; every upload frame
   must fit a wire frame and the sample count must add up. */
static void fuzz_trace(const uint8_t *data, size_t size) {
  static float storage[96];
  fw_trace_t tr;
  fw_snapshot_t snap;
  if (size < 12u) {
    return;
  }
  uint32_t cap = 1u + data[0] % 96u;
  (void)fw_trace_init(&tr, storage, cap);
  uint8_t n = (uint8_t)(data[1] % 10u);
  uint8_t ids[FW_SERIAL_MAX_SIGNALS + 2u];
  for (uint8_t k = 0; k < sizeof ids; k++) {
    ids[k] = (uint8_t)(data[2 + k % 4u] % (FW_SERIAL_SIGNAL_COUNT + 2u));
  }
  float level;
  memcpy(&level, &data[6], sizeof level);
  if (fw_trace_arm(&tr, ids, n, data[10], data[11] % 40u, level,
                   (fw_trace_edge_t)(data[1] % 5u), 1e-4f) != FW_SERIAL_OK) {
    return;
  }
  memset(&snap, 0, sizeof snap);
  for (size_t i = 12; i + 4u <= size; i += 4u) {
    memcpy(&snap.theta_hat_rad, &data[i], 4);
    memcpy(&snap.i_dq_A[1], &data[i], 4);
    snap.step_count = (uint32_t)i;
    fw_trace_sample(&tr, &snap, (data[i] & 1u) != 0u);
    if ((data[i] & 0x1Eu) == 0x1Eu) {
      fw_trace_trigger(&tr, (uint32_t)i);
    }
  }
  if (fw_trace_upload_start(&tr) != FW_SERIAL_OK) {
    return;
  }
  uint8_t type, payload[FW_SERIAL_MAX_PAYLOAD], wire[FW_SERIAL_MAX_ENCODED];
  size_t len, wlen, frames = 0;
  uint32_t samples = 0;
  while (fw_trace_upload_next(&tr, &type, payload, sizeof payload, &len)) {
    if (len > FW_SERIAL_MAX_PAYLOAD ||
        fw_serial_encode(type, (uint16_t)frames, payload, len, wire, sizeof wire, &wlen) !=
            FW_SERIAL_OK) {
      abort();
    }
    if (type == FW_SERIAL_TYPE_TRACE_DATA) {
      samples += payload[6];
    }
    if (++frames > 1000u) {
      abort();
    }
    if (type == FW_SERIAL_TYPE_TRACE_END) {
      if (samples != tr.filled) {
        abort();
      }
      break;
    }
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  fw_serial_decoder_t dec;
  fw_serial_msg_t msg;
  uint32_t ok = 0u, bad = 0u;
  fw_serial_decoder_init(&dec);
  for (size_t i = 0; i < size; i++) {
    uint32_t lost0 = dec.frames_lost, restarts0 = dec.restarts;
    uint16_t next0 = dec.next_seq;
    uint8_t have0 = dec.have_seq;
    fw_serial_status_t st = fw_serial_decoder_push(&dec, data[i], &msg);
    if (st == FW_SERIAL_OK) {
      roundtrip(&msg);
      ok++;
      /* a frame is either in sequence, a forward gap (loss) or one restart */
      uint16_t gap = (uint16_t)(msg.seq - next0);
      uint32_t dl = dec.frames_lost - lost0, dr = dec.restarts - restarts0;
      if (!have0 ? (dl != 0u || dr != 0u)
                 : (gap <= FW_SERIAL_RESTART_GAP ? (dl != gap || dr != 0u)
                                                 : (dl != 0u || dr != 1u))) {
        abort();
      }
    } else if (st != FW_SERIAL_INCOMPLETE) {
      bad++;
      if (dec.frames_lost != lost0 || dec.restarts != restarts0) {
        abort();
      }
    }
  }
  if (dec.frames_ok != ok || dec.frames_bad != bad) {
    abort();
  }
  if (fw_serial_decode(data, size, &msg) == FW_SERIAL_OK) {
    roundtrip(&msg);
  }
  fuzz_trace(data, size);
  /* COBS on arbitrary data */
  if (size <= 1024u) {
    uint8_t enc[1100], dec2[1100];
    size_t n = fw_serial_cobs_encode(data, size, enc, sizeof enc), m = 0;
    if (n == 0u && size > 0u) {
      abort();
    }
    for (size_t i = 0; i < n; i++) {
      if (enc[i] == 0u) {
        abort();
      }
    }
    if (size > 0u &&
        (fw_serial_cobs_decode(enc, n, dec2, sizeof dec2, &m) != FW_SERIAL_OK || m != size ||
         memcmp(dec2, data, size) != 0)) {
      abort();
    }
  }
  return 0;
}
