/**
 * @file test_serial.c
 * @brief Serial link: CRC, COBS vectors, frames, corrupt/truncated frames,
 *        sequence-gap and sender-restart counting, telemetry payload, trace capture and upload.
 */
#include <string.h>

#include "pmlsm/fw_serial.h"
#include "tinytest.h"

static void test_crc(void) {
  const uint8_t s[] = "123456789";
  TT_CHECK(fw_serial_crc16(s, 9) == 0x29B1u);
  TT_CHECK(fw_serial_crc16(s, 0) == 0xFFFFu);
  TT_CHECK(fw_serial_crc16(NULL, 3) == 0xFFFFu);
}

static void check_cobs(const uint8_t *in, size_t n, const uint8_t *exp, size_t m) {
  uint8_t out[600], back[600];
  size_t k = fw_serial_cobs_encode(in, n, out, sizeof out);
  TT_CHECK(k == m);
  TT_CHECK(k == m && memcmp(out, exp, m) == 0);
  size_t r = 0;
  TT_CHECK(fw_serial_cobs_decode(out, k, back, sizeof back, &r) == FW_SERIAL_OK);
  TT_CHECK(r == n && memcmp(back, in, n) == 0);
}

static void test_cobs_vectors(void) {
  /* vectors from the COBS paper / common references */
  const uint8_t a[] = {0x00}, ea[] = {0x01, 0x01};
  const uint8_t b[] = {0x00, 0x00}, eb[] = {0x01, 0x01, 0x01};
  const uint8_t c[] = {0x11, 0x22, 0x00, 0x33}, ec[] = {0x03, 0x11, 0x22, 0x02, 0x33};
  const uint8_t d[] = {0x11, 0x22, 0x33, 0x44}, ed[] = {0x05, 0x11, 0x22, 0x33, 0x44};
  const uint8_t e[] = {0x11, 0x00, 0x00, 0x00}, ee[] = {0x02, 0x11, 0x01, 0x01, 0x01};
  check_cobs(a, 1, ea, 2);
  check_cobs(b, 2, eb, 3);
  check_cobs(c, 4, ec, 5);
  check_cobs(d, 4, ed, 5);
  check_cobs(e, 4, ee, 5);
  /* 254 non-zero bytes: one 0xFF block */
  uint8_t f[255], ef[258];
  for (int i = 0; i < 255; i++) f[i] = (uint8_t)(i + 1);
  ef[0] = 0xFF;
  memcpy(&ef[1], f, 254);
  check_cobs(f, 254, ef, 255); /* 01..FE -> FF 01..FE */
  ef[255] = 0x02;
  ef[256] = 0xFF;
  check_cobs(f, 255, ef, 257); /* 01..FF -> FF 01..FE 02 FF */
  /* output too small */
  uint8_t out[3];
  TT_CHECK(fw_serial_cobs_encode(d, 4, out, sizeof out) == 0);
  /* invalid: zero inside, truncated block */
  uint8_t bad1[] = {0x03, 0x11, 0x00}, bad2[] = {0x05, 0x11, 0x22}, back[16];
  size_t r;
  TT_CHECK(fw_serial_cobs_decode(bad1, 3, back, sizeof back, &r) == FW_SERIAL_ERR_COBS);
  TT_CHECK(fw_serial_cobs_decode(bad2, 3, back, sizeof back, &r) == FW_SERIAL_ERR_COBS);
  TT_CHECK(fw_serial_cobs_decode(bad2, 0, back, sizeof back, &r) == FW_SERIAL_ERR_COBS);
}

static void test_frames(void) {
  uint8_t payload[FW_SERIAL_MAX_PAYLOAD], wire[FW_SERIAL_MAX_ENCODED];
  size_t n = 0;
  fw_serial_msg_t msg;
  for (size_t i = 0; i < sizeof payload; i++) payload[i] = (uint8_t)(i * 7u);
  TT_CHECK(fw_serial_encode(0x11, 0xBEEF, payload, sizeof payload, wire, sizeof wire, &n) ==
           FW_SERIAL_OK);
  TT_CHECK(n <= FW_SERIAL_MAX_ENCODED && wire[n - 1] == 0);
  for (size_t i = 0; i + 1 < n; i++) TT_CHECK(wire[i] != 0);
  TT_CHECK(fw_serial_decode(wire, n - 1, &msg) == FW_SERIAL_OK);
  TT_CHECK(msg.type == 0x11 && msg.seq == 0xBEEF && msg.len == sizeof payload);
  TT_CHECK(memcmp(msg.payload, payload, sizeof payload) == 0);
  TT_CHECK(fw_serial_encode(1, 0, payload, FW_SERIAL_MAX_PAYLOAD + 1, wire, sizeof wire, &n) ==
           FW_SERIAL_ERR_ARG);
  TT_CHECK(fw_serial_encode(1, 0, payload, 10, wire, 5, &n) == FW_SERIAL_ERR_SPACE);
  /* corrupt: flip one byte -> CRC (or COBS) error, never OK */
  TT_CHECK(fw_serial_encode(1, 7, payload, 20, wire, sizeof wire, &n) == FW_SERIAL_OK);
  int crc_errors = 0;
  for (size_t i = 0; i + 1 < n; i++) {
    uint8_t copy[FW_SERIAL_MAX_ENCODED];
    memcpy(copy, wire, n);
    copy[i] ^= 0x40;
    if (copy[i] == 0) copy[i] = 0x41;
    fw_serial_status_t st = fw_serial_decode(copy, n - 1, &msg);
    TT_CHECK(st != FW_SERIAL_OK);
    crc_errors += st == FW_SERIAL_ERR_CRC;
  }
  TT_CHECK(crc_errors > 0);
  /* truncated */
  for (size_t k = 1; k + 1 < n; k++) {
    TT_CHECK(fw_serial_decode(wire, k, &msg) != FW_SERIAL_OK);
  }
  uint8_t tiny[] = {0x03, 0x01, 0x02};
  TT_CHECK(fw_serial_decode(tiny, 3, &msg) == FW_SERIAL_ERR_SHORT);
}

static void test_decoder_stream(void) {
  fw_serial_link_t link;
  fw_serial_decoder_t dec;
  fw_serial_msg_t msg;
  uint8_t wire[FW_SERIAL_MAX_ENCODED], stream[4096];
  size_t len = 0, n;
  fw_serial_link_init(&link);
  fw_serial_decoder_init(&dec);
  for (int k = 0; k < 10; k++) {
    uint8_t p[3] = {(uint8_t)k, 0, (uint8_t)(k * 3)};
    fw_serial_link_send(&link, 1, p, 3, wire, sizeof wire, &n);
    if (k == 3 || k == 4 || k == 7) continue; /* lost on the wire */
    if (k == 5) {
      wire[2] ^= 0x01; /* corrupted */
    }
    memcpy(&stream[len], wire, n);
    len += n;
  }
  /* garbage then a delimiter */
  stream[len++] = 0x55;
  stream[len++] = 0x00;
  int ok = 0, bad = 0;
  for (size_t i = 0; i < len; i++) {
    fw_serial_status_t st = fw_serial_decoder_push(&dec, stream[i], &msg);
    if (st == FW_SERIAL_OK) ok++;
    else if (st != FW_SERIAL_INCOMPLETE) bad++;
  }
  TT_CHECK(ok == 6);
  TT_CHECK(bad == 2);
  TT_CHECK(dec.frames_ok == 6 && dec.frames_bad == 2);
  TT_CHECK(dec.frames_lost == 4); /* 3, 4, 5 (corrupt), 7 */
  /* overlong garbage without delimiter */
  for (int i = 0; i < 600; i++) fw_serial_decoder_push(&dec, 0x77, &msg);
  TT_CHECK(fw_serial_decoder_push(&dec, 0x00, &msg) == FW_SERIAL_ERR_TOO_LONG);
}

/* Counters after feeding frames with the given sequence numbers (one stream). */
static void feed_seqs(fw_serial_decoder_t *dec, const uint16_t *seqs, size_t n) {
  uint8_t wire[FW_SERIAL_MAX_ENCODED], p[1] = {'x'};
  fw_serial_msg_t msg;
  size_t len = 0;
  fw_serial_decoder_init(dec);
  for (size_t k = 0; k < n; k++) {
    TT_CHECK(fw_serial_encode(FW_SERIAL_TYPE_TELEMETRY, seqs[k], p, 1, wire, sizeof wire, &len) ==
             FW_SERIAL_OK);
    for (size_t i = 0; i < len; i++) {
      fw_serial_status_t st = fw_serial_decoder_push(dec, wire[i], &msg);
      TT_CHECK(st == (i + 1 == len ? FW_SERIAL_OK : FW_SERIAL_INCOMPLETE));
    }
    TT_CHECK(msg.seq == seqs[k]);
  }
}

/* Same vectors as test_receiver_sender_restart_is_not_loss in
   tests/python/test_protocol_serial.py (which also runs this decoder on them). */
static void test_decoder_restart(void) {
  fw_serial_decoder_t dec;
  /* drive reset: 100 -> 0 is one restart, not 65,435 lost; then 2 is lost */
  const uint16_t reset[] = {100, 101, 102, 0, 1, 3};
  feed_seqs(&dec, reset, 6);
  TT_CHECK(dec.frames_ok == 6 && dec.frames_bad == 0);
  TT_CHECK(dec.restarts == 1);
  TT_CHECK(dec.frames_lost == 1);
  /* a forward gap across the 16-bit wrap is loss: 0 and 1 */
  const uint16_t wrap[] = {65534, 65535, 2};
  feed_seqs(&dec, wrap, 3);
  TT_CHECK(dec.restarts == 0 && dec.frames_lost == 2);
  /* boundary: a gap of exactly 0x8000 is loss, one more is a restart */
  const uint16_t half[] = {0, 0x8001};
  feed_seqs(&dec, half, 2);
  TT_CHECK(dec.restarts == 0 && dec.frames_lost == 0x8000u);
  const uint16_t over[] = {0, 0x8002};
  feed_seqs(&dec, over, 2);
  TT_CHECK(dec.restarts == 1 && dec.frames_lost == 0);
  /* a repeated frame (seq = next - 1) is a restart too, as in Python */
  const uint16_t again[] = {7, 7};
  feed_seqs(&dec, again, 2);
  TT_CHECK(dec.restarts == 1 && dec.frames_lost == 0);
}

static void test_telemetry(void) {
  fw_snapshot_t s;
  memset(&s, 0, sizeof s);
  s.step_count = 0x01020304u;
  s.theta_hat_rad = 1.25f;
  s.i_dq_A[1] = -3.5f;
  s.statusword = 0x0237;
  uint8_t ids[3] = {FW_SIG_THETA_HAT_RAD, FW_SIG_I_Q_A, FW_SIG_STATUSWORD};
  uint8_t out[64];
  size_t n = fw_serial_telemetry_payload(&s, ids, 3, out, sizeof out);
  TT_CHECK(n == 5 + 3 + 12);
  TT_CHECK(out[0] == 0x04 && out[3] == 0x01 && out[4] == 3 && out[6] == FW_SIG_I_Q_A);
  float v;
  memcpy(&v, &out[8 + 4], 4);
  TT_CHECK_NEAR(v, -3.5, 0.0);
  memcpy(&v, &out[8 + 8], 4);
  TT_CHECK_NEAR(v, 567.0, 0.0);
  TT_CHECK(fw_serial_telemetry_payload(&s, ids, 9, out, sizeof out) == 0);
  TT_CHECK(fw_serial_telemetry_payload(&s, ids, 3, out, 10) == 0);
  TT_CHECK(fw_serial_signal_value(&s, 200) == 0.0f);
}

static void test_trace(void) {
  float storage[100];
  fw_trace_t tr;
  fw_snapshot_t s;
  memset(&s, 0, sizeof s);
  uint8_t ids[2] = {FW_SIG_I_Q_A, FW_SIG_OMEGA_HAT_RADPS};
  TT_CHECK(fw_trace_init(&tr, storage, 100) == FW_SERIAL_OK);
  TT_CHECK(fw_trace_arm(&tr, ids, 2, 50, FW_SIG_I_Q_A, 1.0f, FW_TRACE_EDGE_RISING, 1e-3f) ==
           FW_SERIAL_ERR_ARG); /* pre >= depth */
  TT_CHECK(fw_trace_arm(&tr, ids, 2, 10, FW_SIG_I_Q_A, 1.0f, FW_TRACE_EDGE_RISING, 1e-3f) ==
           FW_SERIAL_OK);
  TT_CHECK(tr.depth == 50);
  /* i_q ramps 0, 0.1, ...; crosses 1.0 at step 10 (0.1*10 = 1.0) */
  uint32_t step;
  for (step = 0; step < 200 && tr.state != FW_TRACE_DONE; step++) {
    s.step_count = step;
    s.i_dq_A[1] = 0.1f * (float)step;
    s.omega_hat_radps = (float)step;
    fw_trace_sample(&tr, &s, false);
  }
  TT_CHECK(tr.state == FW_TRACE_DONE);
  TT_CHECK(tr.pre_kept == 10);
  TT_CHECK(tr.trigger_step == 10 || tr.trigger_step == 11);
  TT_CHECK(fw_trace_upload_start(&tr) == FW_SERIAL_OK);
  uint8_t type, payload[FW_SERIAL_MAX_PAYLOAD];
  size_t len;
  TT_CHECK(fw_trace_upload_next(&tr, &type, payload, sizeof payload, &len));
  TT_CHECK(type == FW_SERIAL_TYPE_TRACE_HEADER && payload[2] == 2);
  uint32_t samples = 0, first_omega_ok = 0, frames = 0;
  float expect = (float)tr.trigger_step - 10.0f;
  while (fw_trace_upload_next(&tr, &type, payload, sizeof payload, &len)) {
    if (type == FW_SERIAL_TYPE_TRACE_END) break;
    TT_CHECK(type == FW_SERIAL_TYPE_TRACE_DATA);
    uint32_t first = (uint32_t)(payload[2] | (payload[3] << 8));
    TT_CHECK(first == samples);
    uint8_t cnt = payload[6];
    for (uint8_t k = 0; k < cnt; k++) {
      float om;
      memcpy(&om, &payload[7 + 8 * k + 4], 4);
      first_omega_ok += om == expect;
      expect += 1.0f;
    }
    samples += cnt;
    frames++;
  }
  TT_CHECK(type == FW_SERIAL_TYPE_TRACE_END);
  TT_CHECK(samples == 50);
  TT_CHECK(first_omega_ok == 50); /* contiguous, oldest first, 10 before the trigger */
  TT_CHECK(frames >= 2);
  TT_CHECK(!fw_trace_upload_next(&tr, &type, payload, sizeof payload, &len));
  /* fault trigger and forced trigger */
  TT_CHECK(fw_trace_arm(&tr, ids, 2, 5, FW_SIG_I_Q_A, 0.0f, FW_TRACE_ON_FAULT, 1e-3f) ==
           FW_SERIAL_OK);
  for (int k = 0; k < 20; k++) fw_trace_sample(&tr, &s, false);
  TT_CHECK(tr.state == FW_TRACE_ARMED);
  fw_trace_sample(&tr, &s, true);
  TT_CHECK(tr.state == FW_TRACE_TRIGGERED);
  TT_CHECK(fw_trace_arm(&tr, ids, 2, 5, FW_SIG_I_Q_A, 0.0f, FW_TRACE_EDGE_EITHER, 1e-3f) ==
           FW_SERIAL_OK);
  fw_trace_trigger(&tr, 3);
  TT_CHECK(tr.state == FW_TRACE_TRIGGERED && tr.pre_kept == 0);
  TT_CHECK(fw_trace_arm(&tr, ids, 0, 5, 0, 0.0f, FW_TRACE_EDGE_EITHER, 1e-3f) == FW_SERIAL_ERR_ARG);
  uint8_t badids[1] = {250};
  TT_CHECK(fw_trace_arm(&tr, badids, 1, 5, 0, 0.0f, FW_TRACE_EDGE_EITHER, 1e-3f) ==
           FW_SERIAL_ERR_ARG);
  TT_CHECK(fw_trace_init(&tr, NULL, 10) == FW_SERIAL_ERR_NULL);
}

/* The byte-at-a-time CRC against the bit-wise definition (poly 0x1021, init
 * 0xFFFF), on every length up to 300 of a pseudo-random message. */
static uint16_t crc16_bitwise(const uint8_t *d, size_t n) {
  uint16_t crc = 0xFFFFu;
  for (size_t i = 0u; i < n; i++) {
    crc = (uint16_t)(crc ^ (uint16_t)((uint16_t)d[i] << 8));
    for (int b = 0; b < 8; b++) {
      crc = (crc & 0x8000u) != 0u ? (uint16_t)((uint16_t)(crc << 1) ^ 0x1021u)
                                  : (uint16_t)(crc << 1);
    }
  }
  return crc;
}

static void test_crc_bytewise_matches_bitwise(void) {
  uint8_t msg[300];
  uint32_t x = 12345u;
  for (size_t i = 0u; i < sizeof msg; i++) {
    x = x * 1103515245u + 12345u;
    msg[i] = (uint8_t)(x >> 16);
  }
  for (size_t n = 0u; n <= sizeof msg; n++) {
    TT_CHECK(fw_serial_crc16(msg, n) == crc16_bitwise(msg, n));
  }
  uint8_t ff[4] = {0xFFu, 0xFFu, 0x00u, 0x80u};
  TT_CHECK(fw_serial_crc16(ff, 4u) == crc16_bitwise(ff, 4u));
}

int main(void) {
  TT_RUN(test_crc);
  TT_RUN(test_crc_bytewise_matches_bitwise);
  TT_RUN(test_cobs_vectors);
  TT_RUN(test_frames);
  TT_RUN(test_decoder_stream);
  TT_RUN(test_decoder_restart);
  TT_RUN(test_telemetry);
  TT_RUN(test_trace);
  return TT_SUMMARY();
}
