/**
 * @file slcan.h
 * @brief The drive end of a serial-line CAN adapter (Lawicel / slcan ASCII
 *        protocol, as python-can's `slcan` interface and the CANable /
 *        CANUSB adapters speak it): a parser fed byte by byte with what the
 *        host writes, and an encoder of the drive's frames for the host.
 *        Used where a board has no CAN transceiver between it and the bench
 *        (the emulated board: a UART of the emulator is its CAN bus).
 *
 * Lines end in CR ('\r'); LF bytes are ignored (hosts that send CR LF).
 * Every line gets one reply: "\r" (ok), "\a" (BEL: error, malformed or not
 * allowed now), "z\r" after an accepted 11-bit frame, "Z\r" after a 29-bit
 * one, or the answer of V, N and F. Commands:
 *
 *   (empty)     ok (python-can sends a bare CR for "no data bitrate")
 *   O / L / C   open the channel (L: listen only) / close it; O and L when
 *               open are refused, C always succeeds
 *   S0..S8      bit rate 10k..1M (only while closed); sXXYY: BTR0/BTR1
 *   V / N       "Vhhss" hardware and software version, "Nxxxx" serial number
 *   F           "Fxx" status flags (slcan_flag), cleared by the read; open only
 *   Z0 / Z1     time stamps off / on (only while closed): 4 hex digits of
 *               milliseconds modulo 60000 appended to every frame to the host
 *   tIIILDD..   11-bit data frame (L = 0..8 data bytes, 2 hex digits each)
 *   rIIIL       11-bit remote frame
 *   TIIIIIIIILDD.., RIIIIIIIIL  29-bit frames: accepted ("Z\r") and dropped,
 *               the drive being an 11-bit CANopen node (counted)
 *
 * Frames from the host are handed over only while the channel is open (not
 * in listen-only mode); the drive's frames go to the host only while it is
 * open (slcan_is_open: the caller drops them otherwise, as an adapter off the
 * bus). A line longer than SLCAN_LINE_MAX is discarded up to its CR and
 * refused; nothing the host sends can overrun a buffer. No globals: the
 * state is the caller's slcan_t.
 */
#ifndef PMLSM_BOARD_SLCAN_H
#define PMLSM_BOARD_SLCAN_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "pmlsm/fw_port.h"

#ifdef __cplusplus
extern "C" {
#endif

#define SLCAN_LINE_MAX 32u  /**< longest line accepted (CR excluded; a 29-bit frame is 26) */
#define SLCAN_REPLY_MAX 8u  /**< longest reply ("Vhhss\r") */
#define SLCAN_FRAME_MAX 32u /**< longest encoded frame ("tIIIL" + 16 + stamp 4 + CR = 26) */

/** Status flags reported by F (Lawicel bit numbers). */
#define SLCAN_F_RX_FULL 0x01u /**< a frame for the drive was lost: its queue was full */
#define SLCAN_F_OVERRUN 0x08u /**< bytes from the host were lost (receive overrun) */

typedef enum {
  SLCAN_CLOSED = 0,
  SLCAN_OPEN = 1,
  SLCAN_LISTEN = 2 /**< open, listen only: frames from the host are refused */
} slcan_channel_t;

/** What one byte completed. */
typedef enum {
  SLCAN_MORE = 0,  /**< inside a line: nothing to do */
  SLCAN_REPLY = 1, /**< a line ended: send the reply */
  SLCAN_FRAME = 2  /**< a line ended with a frame for the drive: hand it over, send the reply */
} slcan_event_t;

/** Reply to one line (not NUL-terminated). */
typedef struct {
  char text[SLCAN_REPLY_MAX];
  uint8_t len;
} slcan_reply_t;

/** Counters (diagnostics, tests). */
typedef struct {
  uint32_t lines_ok;      /**< lines answered with an ok or a frame acknowledgement */
  uint32_t lines_bad;     /**< lines answered with BEL */
  uint32_t frames_in;     /**< 11-bit frames handed to the drive */
  uint32_t frames_ext_in; /**< 29-bit frames accepted and dropped */
  uint32_t frames_out;    /**< frames encoded for the host */
} slcan_counters_t;

/** Parser and channel state, caller-owned. Treat the members as private. */
typedef struct {
  char line[SLCAN_LINE_MAX];
  uint8_t len;
  uint8_t overflow;   /**< the current line is too long: refused at its CR */
  uint8_t channel;    /**< slcan_channel_t */
  uint8_t bitrate;    /**< S code 0..8, SLCAN_BITRATE_BTR after sXXYY */
  uint16_t btr;       /**< BTR0 << 8 | BTR1 after sXXYY */
  uint8_t timestamps; /**< Z1 */
  uint8_t flags;      /**< SLCAN_F_* since the last F */
  char version[4];    /**< V answer */
  char serial[4];     /**< N answer */
  slcan_counters_t count;
} slcan_t;

#define SLCAN_BITRATE_BTR 0xFFu

/**
 * Initialise: channel closed, 1 Mbit/s (S8), no time stamps. version and
 * serial are the 4 characters of the V and N answers (NULL: "0000").
 */
void slcan_init(slcan_t *s, const char *version, const char *serial);

/**
 * Feed one byte the host sent. At a CR the line is interpreted: *reply
 * holds its answer and the result is SLCAN_REPLY, or SLCAN_FRAME when the
 * line was an 11-bit frame for the drive (then in *frame). SLCAN_MORE
 * otherwise (reply->len 0).
 */
slcan_event_t slcan_push(slcan_t *s, uint8_t byte, fw_can_frame_t *frame, slcan_reply_t *reply);

/** True while the channel is open (O or L): the drive's frames go to the host. */
bool slcan_is_open(const slcan_t *s);

/**
 * Encode a frame of the drive for the host ("tIIILDD..\r" or "rIIIL\r",
 * with the time stamp stamp_ms % 60000 when Z1 is set). Returns the length
 * (at most SLCAN_FRAME_MAX), 0 when cap is too small or the frame is not a
 * valid 11-bit frame (identifier above 0x7FF, dlc above 8). Does not look at
 * the channel (slcan_is_open); counts the frame when it returns non-zero.
 */
size_t slcan_encode(slcan_t *s, const fw_can_frame_t *frame, uint32_t stamp_ms, char *out,
                    size_t cap);

/** Raise status flags (SLCAN_F_*), reported and cleared by the next F. */
void slcan_flag(slcan_t *s, uint8_t flags);

/** The counters. */
const slcan_counters_t *slcan_counters(const slcan_t *s);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_BOARD_SLCAN_H */
