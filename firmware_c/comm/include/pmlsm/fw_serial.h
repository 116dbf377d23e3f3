/**
 * @file fw_serial.h
 * @brief Serial link: COBS framing + CRC-16/CCITT-FALSE + sequence numbers,
 *        telemetry frames and trace-buffer (scope) capture and upload.
 *
 * Byte layouts are in docs/protocols.md. One frame on the wire:
 *
 *     COBS( type:u8 | seq:u16le | payload[0..240] | crc16:u16le ) 0x00
 *
 * crc16 = CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no
 * xorout) over type, seq and payload. seq increments by one per frame sent
 * (mod 2^16) so that the receiver counts every lost frame. The decoder counts a
 * forward gap (1..FW_SERIAL_RESTART_GAP modulo 2^16) as lost frames and a
 * larger one, i.e. a jump backwards such as 100 -> 0 after a drive reset, as one
 * sender restart (protocols/serial_link.py does the same).
 *
 * No malloc, no globals: the encoder, decoder and trace state are
 * caller-owned structs; the trace sample storage is a caller-owned array.
 */
#ifndef PMLSM_FW_SERIAL_H
#define PMLSM_FW_SERIAL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "fw_serial_signals.h"
#include "pmlsm/fw_snapshot.h"

#ifdef __cplusplus
extern "C" {
#endif

#define FW_SERIAL_MAX_PAYLOAD 240u
/** type + seq + payload + crc */
#define FW_SERIAL_MAX_RAW (3u + FW_SERIAL_MAX_PAYLOAD + 2u)
/** COBS worst case + delimiter */
#define FW_SERIAL_MAX_ENCODED (FW_SERIAL_MAX_RAW + FW_SERIAL_MAX_RAW / 254u + 2u)
/** Signals per telemetry frame or trace capture. */
#define FW_SERIAL_MAX_SIGNALS 8u
/** Largest sequence gap (mod 2^16) counted as loss; a larger one is a sender restart. */
#define FW_SERIAL_RESTART_GAP 0x8000u

typedef enum {
  FW_SERIAL_TYPE_TELEMETRY = 0x01,
  FW_SERIAL_TYPE_TRACE_HEADER = 0x10,
  FW_SERIAL_TYPE_TRACE_DATA = 0x11,
  FW_SERIAL_TYPE_TRACE_END = 0x12
} fw_serial_frame_type_t;

typedef enum {
  FW_SERIAL_OK = 0,
  FW_SERIAL_INCOMPLETE = 1,   /**< decoder: no complete frame yet */
  FW_SERIAL_ERR_NULL = 2,     /**< NULL argument */
  FW_SERIAL_ERR_ARG = 3,      /**< argument out of range */
  FW_SERIAL_ERR_SPACE = 4,    /**< output buffer too small */
  FW_SERIAL_ERR_COBS = 5,     /**< invalid COBS code sequence */
  FW_SERIAL_ERR_SHORT = 6,    /**< decoded frame shorter than type+seq+crc */
  FW_SERIAL_ERR_CRC = 7,      /**< CRC mismatch */
  FW_SERIAL_ERR_TOO_LONG = 8  /**< no delimiter within FW_SERIAL_MAX_ENCODED bytes */
} fw_serial_status_t;

/** One decoded frame. */
typedef struct {
  uint8_t type;
  uint16_t seq;
  uint16_t len;
  uint8_t payload[FW_SERIAL_MAX_PAYLOAD];
} fw_serial_msg_t;

/** Stream decoder: push bytes, get frames. Counts frames and errors. */
typedef struct {
  uint8_t buf[FW_SERIAL_MAX_ENCODED];
  size_t len;
  uint8_t overflow;   /**< discarding until the next delimiter */
  uint8_t have_seq;
  uint16_t next_seq;
  uint32_t frames_ok;
  uint32_t frames_bad; /**< COBS/CRC/short/too long */
  uint32_t frames_lost; /**< forward gaps in the sequence numbers */
  uint32_t restarts;    /**< backward jumps (gap > FW_SERIAL_RESTART_GAP): sender restarted */
} fw_serial_decoder_t;

/** Encoder state: the next sequence number. */
typedef struct {
  uint16_t seq;
} fw_serial_link_t;

/* ---- framing ---------------------------------------------------------- */

/** CRC-16/CCITT-FALSE ("123456789" -> 0x29B1). */
uint16_t fw_serial_crc16(const uint8_t *data, size_t len);

/** COBS-encode len bytes (no delimiter). Returns the output length, 0 if cap is too small. */
size_t fw_serial_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);

/** COBS-decode (input without the delimiter). */
fw_serial_status_t fw_serial_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap,
                                         size_t *out_len);

/** Build one wire frame (COBS + trailing 0x00) from type, seq and payload. */
fw_serial_status_t fw_serial_encode(uint8_t type, uint16_t seq, const uint8_t *payload,
                                    size_t len, uint8_t *out, size_t cap, size_t *out_len);

/** Decode one frame (bytes between delimiters, delimiter excluded). */
fw_serial_status_t fw_serial_decode(const uint8_t *frame, size_t len, fw_serial_msg_t *msg);

void fw_serial_link_init(fw_serial_link_t *link);
/** fw_serial_encode with the link's sequence number, which is then incremented. */
fw_serial_status_t fw_serial_link_send(fw_serial_link_t *link, uint8_t type,
                                       const uint8_t *payload, size_t len, uint8_t *out,
                                       size_t cap, size_t *out_len);

void fw_serial_decoder_init(fw_serial_decoder_t *dec);
/**
 * Push one byte. Returns FW_SERIAL_OK with *msg filled when a valid frame
 * ends, FW_SERIAL_INCOMPLETE while inside a frame, or the reason a frame
 * was rejected.
 */
fw_serial_status_t fw_serial_decoder_push(fw_serial_decoder_t *dec, uint8_t byte,
                                          fw_serial_msg_t *msg);

/* ---- signals and telemetry --------------------------------------------- */

/** Value of signal id (FW_SIG_*) in a snapshot, as float; 0 for an unknown id. */
float fw_serial_signal_value(const fw_snapshot_t *snap, uint8_t id);

/**
 * Telemetry payload: step:u32 | n:u8 | ids[n] | values f32[n].
 * Returns the payload length, 0 on a bad argument.
 */
size_t fw_serial_telemetry_payload(const fw_snapshot_t *snap, const uint8_t *ids, uint8_t n,
                                   uint8_t *out, size_t cap);

/* ---- trace buffer ------------------------------------------------------ */

typedef enum {
  FW_TRACE_IDLE = 0,
  FW_TRACE_ARMED = 1,     /**< filling the pre-trigger ring, waiting for the trigger */
  FW_TRACE_TRIGGERED = 2, /**< recording the post-trigger part */
  FW_TRACE_DONE = 3,      /**< capture complete, ready for upload */
  FW_TRACE_UPLOADING = 4
} fw_trace_state_t;

typedef enum {
  FW_TRACE_EDGE_RISING = 0,
  FW_TRACE_EDGE_FALLING = 1,
  FW_TRACE_EDGE_EITHER = 2,
  FW_TRACE_ON_FAULT = 3
} fw_trace_edge_t;

/** Trace capture. storage/capacity are caller-owned (floats). */
typedef struct {
  float *storage;
  uint32_t capacity; /**< floats in storage */
  fw_trace_state_t state;
  uint8_t n_sig;
  uint8_t ids[FW_SERIAL_MAX_SIGNALS];
  uint32_t depth;      /**< samples per capture = capacity / n_sig */
  uint32_t pre;        /**< samples kept before the trigger */
  uint8_t trig_sig;
  uint8_t edge;        /**< fw_trace_edge_t */
  float level;
  float prev;          /**< previous trigger-signal value */
  uint8_t have_prev;
  uint32_t wr;         /**< ring write index (samples) */
  uint32_t filled;     /**< samples in the ring */
  uint32_t post_left;  /**< samples still to record after the trigger */
  uint32_t pre_kept;   /**< samples recorded before the trigger */
  uint32_t trigger_step;
  uint32_t start;      /**< ring index of the oldest sample when done */
  uint16_t capture_id;
  float dt_s;
  uint32_t up_next;    /**< upload: next sample to send */
  uint8_t up_stage;    /**< 0 header, 1 data, 2 end */
} fw_trace_t;

/** Attach caller-owned storage (capacity floats). */
fw_serial_status_t fw_trace_init(fw_trace_t *tr, float *storage, uint32_t capacity);

/**
 * Arm a capture of n signals (ids), pre samples before the trigger, trigger
 * on signal trig_sig crossing level with the given edge (or on a fault).
 */
fw_serial_status_t fw_trace_arm(fw_trace_t *tr, const uint8_t *ids, uint8_t n, uint32_t pre,
                                uint8_t trig_sig, float level, fw_trace_edge_t edge,
                                float dt_s);

/** Force the trigger now (ARMED -> TRIGGERED). */
void fw_trace_trigger(fw_trace_t *tr, uint32_t step);

/** Stop: back to IDLE (capture discarded). */
void fw_trace_stop(fw_trace_t *tr);

/** Record one control period (call every step); fault: a fault is latched. */
void fw_trace_sample(fw_trace_t *tr, const fw_snapshot_t *snap, bool fault);

/** DONE -> UPLOADING (restarts an upload already in progress). */
fw_serial_status_t fw_trace_upload_start(fw_trace_t *tr);

/**
 * Next upload frame payload: header, data chunks, end. Returns true and
 * sets *type / *len while uploading; false when nothing (more) to send.
 */
bool fw_trace_upload_next(fw_trace_t *tr, uint8_t *type, uint8_t *payload, size_t cap,
                          size_t *len);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_FW_SERIAL_H */
