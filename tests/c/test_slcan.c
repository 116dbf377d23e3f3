/**
 * @file test_slcan.c
 * @brief The serial-line CAN endpoint (firmware_c/boards/_common/slcan.c)
 *        against what python-can's slcan interface writes and reads
 *        (can/interfaces/slcan.py), and against a reference encoder written
 *        here with snprintf.
 *
 * Checked: python-can's open sequence (C, S8, bare CR, O) is accepted;
 * frames of random identifier, length and data parse to the frame the
 * reference encoder wrote, and the module's encoder writes the same line;
 * frames are refused while closed or listen-only; 29-bit frames are
 * accepted and dropped; malformed and overlong lines are refused with BEL
 * and the next line works; every CR gets exactly one reply; V, N, F, Z.
 */
#include <stdio.h>
#include <string.h>

#include "../../firmware_c/boards/_common/slcan.c"
#include "tinytest.h"

static uint32_t rng_state = 12345u;
static uint32_t rnd(void) {
  rng_state ^= rng_state << 13;
  rng_state ^= rng_state >> 17;
  rng_state ^= rng_state << 5;
  return rng_state;
}

/** Feed a string; the reply of its last CR in *last, the frames counted. */
typedef struct {
  int replies, frames;
  slcan_reply_t last;
  fw_can_frame_t frame;
} feed_t;

static feed_t feed(slcan_t *s, const char *text) {
  feed_t f;
  memset(&f, 0, sizeof f);
  for (const char *p = text; *p != '\0'; p++) {
    fw_can_frame_t fr;
    slcan_reply_t r;
    slcan_event_t ev = slcan_push(s, (uint8_t)*p, &fr, &r);
    if (ev != SLCAN_MORE) {
      f.replies++;
      f.last = r;
    }
    if (ev == SLCAN_FRAME) {
      f.frames++;
      f.frame = fr;
    }
    if (ev == SLCAN_MORE && r.len != 0u) {
      f.replies += 1000; /* a reply without a line end: a bug */
    }
  }
  return f;
}

static int reply_is(const feed_t *f, const char *want) {
  return f->last.len == strlen(want) && memcmp(f->last.text, want, f->last.len) == 0;
}

/** python-can's line for a frame (slcanBus.send): "t%03X%d" + hex data (upper case). */
static void ref_line(const fw_can_frame_t *f, char *out, size_t cap) {
  int n = snprintf(out, cap, "%c%03X%d", f->rtr ? 'r' : 't', f->id, f->dlc);
  if (!f->rtr) {
    for (unsigned i = 0; i < f->dlc; i++) {
      n += snprintf(out + n, cap - (size_t)n, "%02X", f->data[i]);
    }
  }
  snprintf(out + n, cap - (size_t)n, "\r");
}

static void test_python_can_open_sequence(void) {
  slcan_t s;
  slcan_init(&s, "0103", "E386");
  TT_CHECK(!slcan_is_open(&s));
  const char *seq[] = {"C\r", "S8\r", "\r", "O\r"};
  for (int i = 0; i < 4; i++) {
    feed_t f = feed(&s, seq[i]);
    TT_CHECK(f.replies == 1 && reply_is(&f, "\r"));
  }
  TT_CHECK(slcan_is_open(&s));
  TT_CHECK(s.bitrate == 8u);
  /* without a bit rate python-can sends O alone: also from closed */
  slcan_init(&s, NULL, NULL);
  feed_t f = feed(&s, "O\r");
  TT_CHECK(reply_is(&f, "\r") && slcan_is_open(&s));
  /* O when open: refused (Lawicel), the channel stays open; C always ok */
  f = feed(&s, "O\r");
  TT_CHECK(reply_is(&f, "\a") && slcan_is_open(&s));
  f = feed(&s, "C\r");
  TT_CHECK(reply_is(&f, "\r") && !slcan_is_open(&s));
  f = feed(&s, "C\r");
  TT_CHECK(reply_is(&f, "\r"));
}

static void test_frames_match_reference(void) {
  slcan_t s, enc;
  slcan_init(&s, NULL, NULL);
  slcan_init(&enc, NULL, NULL);
  feed(&s, "O\r");
  int bad = 0;
  for (int k = 0; k < 20000; k++) {
    fw_can_frame_t want;
    memset(&want, 0, sizeof want);
    want.id = (uint16_t)(rnd() & 0x7FFu);
    want.dlc = (uint8_t)(rnd() % 9u);
    want.rtr = (rnd() % 8u) == 0u;
    if (!want.rtr) {
      for (unsigned i = 0; i < want.dlc; i++)
        want.data[i] = (uint8_t)rnd();
    }
    char line[64];
    ref_line(&want, line, sizeof line);
    if (k % 2) { /* lower case hex is accepted too */
      for (char *p = line + 1; *p; p++)
        if (*p >= 'A' && *p <= 'F')
          *p = (char)(*p - 'A' + 'a');
    }
    feed_t f = feed(&s, line);
    if (f.frames != 1 || f.replies != 1 || !reply_is(&f, "z\r") || f.frame.id != want.id ||
        f.frame.dlc != want.dlc || f.frame.rtr != want.rtr ||
        memcmp(f.frame.data, want.data, 8) != 0) {
      bad++;
    }
    /* the module's encoder writes python-can's line (upper case) */
    char out[SLCAN_FRAME_MAX], ref[64];
    ref_line(&want, ref, sizeof ref);
    size_t n = slcan_encode(&enc, &want, 0u, out, sizeof out);
    if (n != strlen(ref) || memcmp(out, ref, n) != 0)
      bad++;
  }
  TT_CHECK(bad == 0);
  TT_CHECK(s.count.frames_in == 20000u);
  TT_CHECK(enc.count.frames_out == 20000u);
}

static void test_closed_and_listen_refuse_frames(void) {
  slcan_t s;
  slcan_init(&s, NULL, NULL);
  feed_t f = feed(&s, "t1232ABCD\r");
  TT_CHECK(f.frames == 0 && reply_is(&f, "\a"));
  f = feed(&s, "L\r");
  TT_CHECK(reply_is(&f, "\r") && slcan_is_open(&s)); /* drive frames still go out */
  f = feed(&s, "t1232ABCD\r");
  TT_CHECK(f.frames == 0 && reply_is(&f, "\a"));
  f = feed(&s, "C\rO\rt1232ABCD\r");
  TT_CHECK(f.frames == 1 && f.replies == 3 && reply_is(&f, "z\r"));
  TT_CHECK(f.frame.id == 0x123u && f.frame.dlc == 2u && f.frame.data[0] == 0xABu &&
           f.frame.data[1] == 0xCDu);
}

static void test_extended_frames_dropped(void) {
  slcan_t s;
  slcan_init(&s, NULL, NULL);
  feed(&s, "O\r");
  feed_t f = feed(&s, "T1ABCDEF82DEAD\r");
  TT_CHECK(f.frames == 0 && reply_is(&f, "Z\r"));
  f = feed(&s, "R1FFFFFFF0\r");
  TT_CHECK(f.frames == 0 && reply_is(&f, "Z\r"));
  TT_CHECK(s.count.frames_ext_in == 2u);
  f = feed(&s, "T200000000\r"); /* above 29 bits */
  TT_CHECK(f.frames == 0 && reply_is(&f, "\a"));
}

static void test_malformed_lines(void) {
  slcan_t s;
  slcan_init(&s, NULL, NULL);
  feed(&s, "O\r");
  const char *bad[] = {"t12\r",
                       "t1232AB\r",
                       "t1232ABCDEF\r",
                       "t12G0\r",
                       "t8000\r",
                       "t1239001122334455667788\r",
                       "t123\r",
                       "r1230x\r",
                       "r12\r",
                       "X\r",
                       "O1\r",
                       "S9\r",
                       "Sx\r",
                       "s12\r",
                       "Z2\r",
                       "V1\r",
                       "d1238DEADBEEFDEADBEEF\r",
                       "t-230\r",
                       "\x01\x02\xff\r"};
  uint32_t bad0 = s.count.lines_bad;
  for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    feed_t f = feed(&s, bad[i]);
    TT_CHECK(f.replies == 1 && f.frames == 0 && reply_is(&f, "\a"));
  }
  TT_CHECK(s.count.lines_bad - bad0 == sizeof bad / sizeof bad[0]);
  /* settings only while closed */
  feed_t f = feed(&s, "S6\r");
  TT_CHECK(reply_is(&f, "\a"));
  f = feed(&s, "Z1\r");
  TT_CHECK(reply_is(&f, "\a"));
  f = feed(&s, "C\rS6\r");
  TT_CHECK(reply_is(&f, "\r") && s.bitrate == 6u);
  f = feed(&s, "s031C\r");
  TT_CHECK(reply_is(&f, "\r") && s.bitrate == SLCAN_BITRATE_BTR && s.btr == 0x031Cu);
}

static void test_long_line_and_recovery(void) {
  slcan_t s;
  slcan_init(&s, NULL, NULL);
  feed(&s, "O\r");
  char line[300];
  memset(line, 't', sizeof line);
  line[sizeof line - 2] = '\r';
  line[sizeof line - 1] = '\0';
  feed_t f = feed(&s, line);
  TT_CHECK(f.replies == 1 && f.frames == 0 && reply_is(&f, "\a"));
  /* exactly SLCAN_LINE_MAX bytes is not too long (but malformed here) */
  memset(line, '0', SLCAN_LINE_MAX);
  line[0] = 'T';
  line[SLCAN_LINE_MAX] = '\r';
  line[SLCAN_LINE_MAX + 1] = '\0';
  f = feed(&s, line);
  TT_CHECK(f.replies == 1 && reply_is(&f, "\a"));
  TT_CHECK(s.len == 0u && s.overflow == 0u);
  f = feed(&s, "t7FF0\r");
  TT_CHECK(f.frames == 1 && f.frame.id == 0x7FFu && f.frame.dlc == 0u);
  /* CR LF line ends */
  f = feed(&s, "t0011FF\r\nt0021EE\r\n");
  TT_CHECK(f.frames == 2 && f.replies == 2 && f.frame.id == 0x002u && f.frame.data[0] == 0xEEu);
  /* empty line */
  f = feed(&s, "\r");
  TT_CHECK(f.replies == 1 && reply_is(&f, "\r"));
}

static void test_info_and_flags(void) {
  slcan_t s;
  slcan_init(&s, "0103", "E3");
  feed_t f = feed(&s, "V\r");
  TT_CHECK(reply_is(&f, "V0103\r"));
  f = feed(&s, "N\r");
  TT_CHECK(reply_is(&f, "NE300\r")); /* short serial padded */
  f = feed(&s, "F\r");
  TT_CHECK(reply_is(&f, "\a")); /* closed */
  feed(&s, "O\r");
  f = feed(&s, "F\r");
  TT_CHECK(reply_is(&f, "F00\r"));
  slcan_flag(&s, SLCAN_F_RX_FULL);
  slcan_flag(&s, SLCAN_F_OVERRUN);
  f = feed(&s, "F\r");
  TT_CHECK(reply_is(&f, "F09\r"));
  f = feed(&s, "F\r");
  TT_CHECK(reply_is(&f, "F00\r")); /* cleared by the read */
}

static void test_encode(void) {
  slcan_t s;
  slcan_init(&s, NULL, NULL);
  fw_can_frame_t fr;
  memset(&fr, 0, sizeof fr);
  fr.id = 0x701u;
  fr.dlc = 1u;
  fr.data[0] = 0x05u;
  char out[SLCAN_FRAME_MAX];
  size_t n = slcan_encode(&s, &fr, 0u, out, sizeof out);
  TT_CHECK(n == 8u && memcmp(out, "t701105\r", 8) == 0);
  TT_CHECK(slcan_encode(&s, &fr, 0u, out, 7u) == 0u); /* does not fit */
  /* time stamps: milliseconds modulo 60000 as 4 hex digits */
  feed(&s, "Z1\r");
  n = slcan_encode(&s, &fr, 61234u, out, sizeof out);
  TT_CHECK(n == 12u && memcmp(out, "t70110504D2\r", 12) == 0);
  fr.id = 0x800u;
  TT_CHECK(slcan_encode(&s, &fr, 0u, out, sizeof out) == 0u);
  fr.id = 0x7FFu;
  fr.dlc = 9u;
  TT_CHECK(slcan_encode(&s, &fr, 0u, out, sizeof out) == 0u);
  /* a full 8-byte frame with stamp fits SLCAN_FRAME_MAX */
  fr.dlc = 8u;
  n = slcan_encode(&s, &fr, 59999u, out, sizeof out);
  TT_CHECK(n == 26u && n <= SLCAN_FRAME_MAX);
}

static void test_random_bytes_one_reply_per_cr(void) {
  slcan_t s;
  slcan_init(&s, NULL, NULL);
  int ok = 1;
  uint32_t crs = 0u;
  for (int k = 0; k < 200000; k++) {
    uint8_t b = (uint8_t)rnd();
    if (rnd() % 16u == 0u)
      b = '\r';
    if (rnd() % 64u == 0u)
      b = 'O';
    fw_can_frame_t fr;
    slcan_reply_t r;
    slcan_event_t ev = slcan_push(&s, b, &fr, &r);
    if (b == '\r') {
      crs++;
      if (ev == SLCAN_MORE || r.len == 0u || r.len > SLCAN_REPLY_MAX)
        ok = 0;
    } else if (ev != SLCAN_MORE || r.len != 0u) {
      ok = 0;
    }
    if (ev == SLCAN_FRAME && (fr.id > 0x7FFu || fr.dlc > 8u))
      ok = 0;
    if (s.len > SLCAN_LINE_MAX)
      ok = 0;
  }
  TT_CHECK(ok);
  TT_CHECK(s.count.lines_ok + s.count.lines_bad == crs);
}

int main(void) {
  TT_RUN(test_python_can_open_sequence);
  TT_RUN(test_frames_match_reference);
  TT_RUN(test_closed_and_listen_refuse_frames);
  TT_RUN(test_extended_frames_dropped);
  TT_RUN(test_malformed_lines);
  TT_RUN(test_long_line_and_recovery);
  TT_RUN(test_info_and_flags);
  TT_RUN(test_encode);
  TT_RUN(test_random_bytes_one_reply_per_cr);
  return TT_SUMMARY();
}
