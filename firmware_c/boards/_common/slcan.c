/**
 * @file slcan.c
 * @brief Serial-line CAN endpoint (slcan.h).
 */
#include "slcan.h"

#include <string.h>

static const char HEX[] = "0123456789ABCDEF";

/** Value of a hex digit, -1 when c is none. */
static int hex_val(char c) {
  if (c >= '0' && c <= '9') {
    return c - '0';
  }
  if (c >= 'A' && c <= 'F') {
    return c - 'A' + 10;
  }
  if (c >= 'a' && c <= 'f') {
    return c - 'a' + 10;
  }
  return -1;
}

/** n hex digits at p into *v; false when one is not a hex digit. */
static bool hex_field(const char *p, unsigned n, uint32_t *v) {
  uint32_t x = 0u;
  for (unsigned i = 0u; i < n; i++) {
    const int d = hex_val(p[i]);
    if (d < 0) {
      return false;
    }
    x = (x << 4) | (uint32_t)d;
  }
  *v = x;
  return true;
}

/** The 4 characters of a V or N answer: src up to its NUL, printable, padded with '0'. */
static void copy4(char dst[4], const char *src) {
  bool end = src == NULL;
  for (unsigned i = 0u; i < 4u; i++) {
    char c = end ? '0' : src[i];
    if (c == '\0') {
      end = true;
      c = '0';
    } else if (c < 0x21 || c > 0x7E) {
      c = '0';
    }
    dst[i] = c;
  }
}

void slcan_init(slcan_t *s, const char *version, const char *serial) {
  if (s == NULL) {
    return;
  }
  memset(s, 0, sizeof *s);
  s->channel = (uint8_t)SLCAN_CLOSED;
  s->bitrate = 8u;
  copy4(s->version, version);
  copy4(s->serial, serial);
}

bool slcan_is_open(const slcan_t *s) {
  return s != NULL && s->channel != (uint8_t)SLCAN_CLOSED;
}

void slcan_flag(slcan_t *s, uint8_t flags) {
  if (s != NULL) {
    s->flags = (uint8_t)(s->flags | flags);
  }
}

const slcan_counters_t *slcan_counters(const slcan_t *s) {
  return s != NULL ? &s->count : NULL;
}

static void reply_set(slcan_reply_t *r, const char *text, uint8_t len) {
  memcpy(r->text, text, len);
  r->len = len;
}

/**
 * A frame line: t/r (11-bit, id_digits 3) or T/R (29-bit, 8). Fills f for an
 * 11-bit one. False when malformed.
 */
static bool parse_frame(const char *p, unsigned len, unsigned id_digits, bool remote,
                        fw_can_frame_t *f) {
  uint32_t id;
  if (len < 1u + id_digits + 1u || !hex_field(p + 1, id_digits, &id)) {
    return false;
  }
  const char l = p[1u + id_digits];
  if (l < '0' || l > '8') {
    return false;
  }
  const unsigned dlc = (unsigned)(l - '0');
  const unsigned want = 1u + id_digits + 1u + (remote ? 0u : 2u * dlc);
  if (len != want || id > (id_digits == 3u ? 0x7FFu : 0x1FFFFFFFu)) {
    return false;
  }
  memset(f, 0, sizeof *f);
  f->id = (uint16_t)(id & 0x7FFu);
  f->dlc = (uint8_t)dlc;
  f->rtr = remote ? 1u : 0u;
  if (!remote) {
    for (unsigned i = 0u; i < dlc; i++) {
      uint32_t b;
      if (!hex_field(p + 2u + id_digits + 2u * i, 2u, &b)) {
        return false;
      }
      f->data[i] = (uint8_t)b;
    }
  }
  return true;
}

/** Interpret the completed line. */
static slcan_event_t line_end(slcan_t *s, fw_can_frame_t *frame, slcan_reply_t *reply) {
  static const char OK[] = "\r", BEL[] = "\a";
  const char *p = s->line;
  const unsigned len = s->len;
  const bool closed = s->channel == (uint8_t)SLCAN_CLOSED;
  bool ok = false;
  fw_can_frame_t f;
  if (len == 0u) {
    ok = true; /* empty line */
  } else {
    switch (p[0]) {
    case 'O':
    case 'L':
      if (len == 1u && closed) {
        s->channel = (uint8_t)(p[0] == 'O' ? SLCAN_OPEN : SLCAN_LISTEN);
        ok = true;
      }
      break;
    case 'C':
      if (len == 1u) {
        s->channel = (uint8_t)SLCAN_CLOSED;
        ok = true;
      }
      break;
    case 'S':
      if (len == 2u && closed && p[1] >= '0' && p[1] <= '8') {
        s->bitrate = (uint8_t)(p[1] - '0');
        ok = true;
      }
      break;
    case 's': {
      uint32_t btr;
      if (len == 5u && closed && hex_field(p + 1, 4u, &btr)) {
        s->bitrate = SLCAN_BITRATE_BTR;
        s->btr = (uint16_t)btr;
        ok = true;
      }
      break;
    }
    case 'Z':
      if (len == 2u && closed && (p[1] == '0' || p[1] == '1')) {
        s->timestamps = (uint8_t)(p[1] - '0');
        ok = true;
      }
      break;
    case 'V':
    case 'N':
      if (len == 1u) {
        reply->text[0] = p[0];
        memcpy(&reply->text[1], p[0] == 'V' ? s->version : s->serial, 4u);
        reply->text[5] = '\r';
        reply->len = 6u;
        s->count.lines_ok++;
        return SLCAN_REPLY;
      }
      break;
    case 'F':
      if (len == 1u && !closed) {
        reply->text[0] = 'F';
        reply->text[1] = HEX[s->flags >> 4];
        reply->text[2] = HEX[s->flags & 0xFu];
        reply->text[3] = '\r';
        reply->len = 4u;
        s->flags = 0u;
        s->count.lines_ok++;
        return SLCAN_REPLY;
      }
      break;
    case 't':
    case 'r':
      if (s->channel == (uint8_t)SLCAN_OPEN && parse_frame(p, len, 3u, p[0] == 'r', &f)) {
        *frame = f;
        reply_set(reply, "z\r", 2u);
        s->count.lines_ok++;
        s->count.frames_in++;
        return SLCAN_FRAME;
      }
      break;
    case 'T':
    case 'R':
      if (s->channel == (uint8_t)SLCAN_OPEN && parse_frame(p, len, 8u, p[0] == 'R', &f)) {
        reply_set(reply, "Z\r", 2u); /* accepted, not for an 11-bit node */
        s->count.lines_ok++;
        s->count.frames_ext_in++;
        return SLCAN_REPLY;
      }
      break;
    default:
      break;
    }
  }
  if (ok) {
    reply_set(reply, OK, 1u);
    s->count.lines_ok++;
  } else {
    reply_set(reply, BEL, 1u);
    s->count.lines_bad++;
  }
  return SLCAN_REPLY;
}

slcan_event_t slcan_push(slcan_t *s, uint8_t byte, fw_can_frame_t *frame, slcan_reply_t *reply) {
  if (s == NULL || frame == NULL || reply == NULL) {
    return SLCAN_MORE;
  }
  reply->len = 0u;
  if (byte == (uint8_t)'\n') {
    return SLCAN_MORE; /* CR LF from a terminal-style host */
  }
  if (byte != (uint8_t)'\r') {
    if (s->len < SLCAN_LINE_MAX) {
      s->line[s->len++] = (char)byte;
    } else {
      s->overflow = 1u;
    }
    return SLCAN_MORE;
  }
  slcan_event_t ev;
  if (s->overflow) {
    reply_set(reply, "\a", 1u);
    s->count.lines_bad++;
    ev = SLCAN_REPLY;
  } else {
    ev = line_end(s, frame, reply);
  }
  s->len = 0u;
  s->overflow = 0u;
  return ev;
}

size_t slcan_encode(slcan_t *s, const fw_can_frame_t *frame, uint32_t stamp_ms, char *out,
                    size_t cap) {
  if (s == NULL || frame == NULL || out == NULL || frame->id > 0x7FFu || frame->dlc > 8u) {
    return 0u;
  }
  const unsigned dlc = frame->dlc;
  const size_t need = 5u + (frame->rtr ? 0u : 2u * dlc) + (s->timestamps ? 4u : 0u) + 1u; /* CR */
  if (cap < need) {
    return 0u;
  }
  size_t n = 0u;
  out[n++] = frame->rtr ? 'r' : 't';
  out[n++] = HEX[(frame->id >> 8) & 0xFu];
  out[n++] = HEX[(frame->id >> 4) & 0xFu];
  out[n++] = HEX[frame->id & 0xFu];
  out[n++] = (char)('0' + dlc);
  if (!frame->rtr) {
    for (unsigned i = 0u; i < dlc; i++) {
      out[n++] = HEX[frame->data[i] >> 4];
      out[n++] = HEX[frame->data[i] & 0xFu];
    }
  }
  if (s->timestamps) {
    const uint32_t t = stamp_ms % 60000u;
    for (int sh = 12; sh >= 0; sh -= 4) {
      out[n++] = HEX[(t >> (unsigned)sh) & 0xFu];
    }
  }
  out[n++] = '\r';
  s->count.frames_out++;
  return n;
}
