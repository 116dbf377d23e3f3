/**
 * @file co_node.h
 * @brief Small CANopen slave (CiA 301) for the drive: NMT, SDO server
 *        (expedited + segmented), 4 RPDO / 4 TPDO with SDO-configurable
 *        mapping, SYNC, heartbeat producer and consumer, EMCY.
 *
 * No malloc, no globals: everything lives in a caller-owned co_node_t.
 * The object dictionary is generated from protocols/od.yaml (co_od.h).
 *
 * Threading: co_node_rx_isr() may be called from the CAN receive interrupt;
 * it only copies the frame into a single-producer/single-consumer ring.
 * Everything else (co_node_process_rx/tx, OD access, EMCY, tx_pop) runs in
 * the control task. Time is passed in explicitly (now_us, wrapping).
 *
 *     co_node_t node;
 *     co_node_init(&node, 5, &callbacks);      // queues the boot-up message
 *     ISR:  co_node_rx_isr(&node, &frame);
 *     task: co_node_process_rx(&node, now_us); // NMT, SDO, SYNC, RPDO, HB in
 *           ... application ...
 *           co_node_process_tx(&node, now_us); // TPDO events, HB out, HB timeouts
 *           while (co_node_tx_pop(&node, &f)) can_send(&f);
 */
#ifndef PMLSM_CO_NODE_H
#define PMLSM_CO_NODE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "co_od_table.h"
#include "pmlsm/co_od.h"
#include "pmlsm/fw_port.h"

#ifdef __cplusplus
extern "C" {
#endif

#define CO_QUEUE_LEN 64u    /**< frames per queue (power of two) */
#define CO_SDO_BUF_LEN 32u  /**< largest object moved by segmented SDO */
#define CO_SDO_TIMEOUT_US 1000000u
#define CO_HB_CONSUMERS 2u  /**< sub-indices of 0x1016 */

/** CiA 301 signatures: 'save' written to 0x1010:1 stores the parameters,
 *  'load' written to 0x1011:1 restores the defaults (ASCII, little endian). */
#define CO_SIGNATURE_SAVE 0x65766173u
#define CO_SIGNATURE_LOAD 0x64616F6Cu

/** NMT states (values as sent in the heartbeat). */
typedef enum {
  CO_NMT_INITIALISING = 0x00,
  CO_NMT_STOPPED = 0x04,
  CO_NMT_OPERATIONAL = 0x05,
  CO_NMT_PRE_OPERATIONAL = 0x7F
} co_nmt_state_t;

/** Result of the node functions. */
typedef enum {
  CO_OK = 0,
  CO_ERR_NULL = 1,    /**< NULL argument */
  CO_ERR_ARG = 2,     /**< argument out of range (e.g. node id) */
  CO_ERR_FULL = 3,    /**< queue full, frame dropped */
  CO_ERR_STATE = 4    /**< not allowed in the NMT state */
} co_status_t;

/** Events reported to the application. */
typedef enum {
  CO_EV_NMT = 1,        /**< arg: new co_nmt_state_t */
  CO_EV_RESET_NODE = 2, /**< OD was reset to defaults (NMT reset node) */
  CO_EV_RESET_COMM = 3, /**< communication area reset (NMT reset communication) */
  CO_EV_HB_LOST = 4,    /**< arg: node id whose heartbeat timed out */
  CO_EV_HB_RESUMED = 5, /**< arg: node id heard again */
  CO_EV_SYNC = 6,       /**< a SYNC was processed */
  CO_EV_RPDO = 7,       /**< arg: RPDO number 0..3 whose data was applied */
  CO_EV_RPDO_TIMEOUT = 8 /**< arg: RPDO number 0..3 not applied within its event
                              timer (0x1400+n:5); once, until it is applied again */
} co_event_t;

/**
 * Called for every write (SDO or RPDO) after the generic checks passed and
 * before the value is stored. Return CO_ABORT_NONE to accept, an abort code
 * to refuse (the value is then not stored).
 *
 * 0x1010 (store parameters) and 0x1011 (restore defaults), sub-index >= 1,
 * are commands: the node checks the CiA 301 signature ('save' / 'load',
 * else abort 0x08000020), calls the hook to do the work (no hook: abort
 * 0x08000020) and never stores the signature: reading keeps returning the
 * storage capabilities the application put there.
 */
typedef co_abort_t (*co_write_hook_t)(void *ctx, uint16_t index, uint8_t sub,
                                      const uint8_t *data, size_t len);
/** Event notification (may be NULL). */
typedef void (*co_event_hook_t)(void *ctx, co_event_t ev, uint32_t arg);

typedef struct {
  void *ctx;
  co_write_hook_t on_write;
  co_event_hook_t on_event;
} co_callbacks_t;

/** Single-producer / single-consumer frame ring. */
typedef struct {
  fw_can_frame_t buf[CO_QUEUE_LEN];
  volatile uint32_t head; /**< written by the producer only */
  volatile uint32_t tail; /**< written by the consumer only */
  volatile uint32_t dropped;
} co_queue_t;

typedef enum {
  CO_SDO_IDLE = 0,
  CO_SDO_DOWNLOAD = 1, /**< segmented download in progress */
  CO_SDO_UPLOAD = 2    /**< segmented upload in progress */
} co_sdo_state_t;

typedef struct {
  co_sdo_state_t state;
  uint16_t index;
  uint8_t sub;
  uint16_t pos;       /**< OD table position */
  uint8_t toggle;
  uint8_t size_known; /**< download: size indicated by the client */
  uint16_t size;      /**< bytes to move */
  uint16_t done;      /**< bytes moved */
  uint32_t last_us;   /**< time of the last frame, for the timeout */
  uint8_t buf[CO_SDO_BUF_LEN];
} co_sdo_t;

typedef struct {
  uint8_t pending; /**< synchronous RPDO received, applied at the next SYNC */
  uint8_t dlc;
  uint8_t data[8];
  uint8_t watched;   /**< deadline monitoring armed (applied once since OPERATIONAL
                          or since the communication parameters were written) */
  uint8_t timed_out; /**< CO_EV_RPDO_TIMEOUT reported, cleared when applied again */
  uint32_t applied_us; /**< time the data was last applied */
} co_rpdo_rt_t;

typedef struct {
  uint8_t sent_once;
  uint8_t sync_count;
  uint8_t last_len;
  uint8_t last[8];
  uint32_t last_tx_us;
} co_tpdo_rt_t;

typedef struct {
  uint8_t active; /**< a heartbeat was heard since configuration */
  uint8_t lost;
  uint8_t state;  /**< last NMT state heard */
  uint32_t last_us;
} co_hb_rt_t;

/** Counters for diagnostics and tests. */
typedef struct {
  uint32_t rx_frames;
  uint32_t tx_frames;
  uint32_t sdo_aborts;     /**< aborts sent */
  uint32_t rpdo_errors;    /**< RPDO too short or a mapped write refused */
  uint32_t rpdo_timeouts;  /**< RPDO event-timer deadlines missed */
  uint32_t emcy_sent;
} co_counters_t;

/** The node. Allocate it yourself; treat the members as private. */
typedef struct {
  uint8_t node_id;
  co_nmt_state_t nmt;
  uint8_t od[CO_OD_RAM_SIZE];
  co_queue_t rxq;
  co_queue_t txq;
  co_sdo_t sdo;
  co_rpdo_rt_t rpdo[CO_OD_NR_RPDO];
  co_tpdo_rt_t tpdo[CO_OD_NR_TPDO];
  co_hb_rt_t hb[CO_HB_CONSUMERS];
  uint32_t now_us;
  uint32_t hb_last_us;
  co_callbacks_t cb;
  co_counters_t count;
} co_node_t;

/** Reset the OD, queue the boot-up message, enter PRE-OPERATIONAL. node_id 1..127. */
co_status_t co_node_init(co_node_t *node, uint8_t node_id, const co_callbacks_t *cb);

/** Receive path (ISR side): copy the frame into the RX ring. */
co_status_t co_node_rx_isr(co_node_t *node, const fw_can_frame_t *frame);

/** Control task: process queued frames (NMT, SDO, SYNC, RPDO, heartbeats). */
void co_node_process_rx(co_node_t *node, uint32_t now_us);

/** Control task: event/timer TPDOs, heartbeat producer, heartbeat consumer timeouts. */
void co_node_process_tx(co_node_t *node, uint32_t now_us);

/** Next frame to transmit; false when the TX queue is empty. */
bool co_node_tx_pop(co_node_t *node, fw_can_frame_t *frame);

/** Send an EMCY (error code, error register 0x1001, 5 manufacturer bytes or NULL). */
co_status_t co_node_emcy(co_node_t *node, uint16_t code, uint8_t err_reg,
                         const uint8_t msef[5]);

/** Current NMT state. */
co_nmt_state_t co_node_nmt(const co_node_t *node);

/**
 * Write an object through every check an SDO download gets (existence,
 * access, length, limits, PDO rules, the write hook). Returns the abort code.
 */
co_abort_t co_node_write(co_node_t *node, uint16_t index, uint8_t sub, const uint8_t *data,
                         size_t len);
/** Read an object as an SDO upload would; *len in: capacity, out: bytes. */
co_abort_t co_node_read(const co_node_t *node, uint16_t index, uint8_t sub, uint8_t *buf,
                        size_t *len);

/* Direct OD access for the application (no checks, no hooks). pos: CO_OD_iiii_ss. */
uint32_t co_node_get_u32(const co_node_t *node, uint16_t pos);
int32_t co_node_get_i32(const co_node_t *node, uint16_t pos);
float co_node_get_f32(const co_node_t *node, uint16_t pos);
void co_node_set_u32(co_node_t *node, uint16_t pos, uint32_t v);
void co_node_set_i32(co_node_t *node, uint16_t pos, int32_t v);
void co_node_set_f32(co_node_t *node, uint16_t pos, float v);
void co_node_set_str(co_node_t *node, uint16_t pos, const char *s);

/*
 * Per-period OD access for the application by compile-time handle: the
 * generated CO_OD_OFF_<index>_<sub> / CO_OD_LEN_<index>_<sub> (co_od_table.h)
 * locate the value in the OD RAM, so no lookup and no check runs; the value is
 * stored exactly as co_node_set_u32 / _i32 / _f32 store it (integers: the
 * entry's LEN low bytes, little endian). ii_ss is the entry as in the position
 * constants, e.g. CO_NODE_PUT(node, 6041_00, sw).
 */
static inline void co_node_put_at(co_node_t *node, uint16_t off, uint16_t len, uint32_t v) {
  co_le_store(&node->od[off], len, v);
}
static inline uint32_t co_node_get_at(const co_node_t *node, uint16_t off, uint16_t len) {
  return co_le_load(&node->od[off], len);
}
/** Signed value of an entry of len (1..4) bytes: sign-extended as co_node_get_i32 does. */
static inline int32_t co_node_get_i_at(const co_node_t *node, uint16_t off, uint16_t len) {
  uint32_t raw = co_le_load(&node->od[off], len);
  if (len >= 4u) {
    return (int32_t)raw;
  }
  uint32_t m = 1u << (8u * len - 1u);
  return (int32_t)(raw ^ m) - (int32_t)m;
}
static inline void co_node_put_f32_at(co_node_t *node, uint16_t off, float v) {
  co_le_store_f32(&node->od[off], v);
}
static inline float co_node_get_f32_at(const co_node_t *node, uint16_t off) {
  return co_le_load_f32(&node->od[off]);
}
/* 0 when the entry is 4 bytes long; else a compile error (negative array size) */
#define CO_NODE_LEN4_(ii_ss) ((void)sizeof(char[CO_OD_LEN_##ii_ss == 4u ? 1 : -1]))
#define CO_NODE_PUT(node, ii_ss, v) \
  co_node_put_at((node), CO_OD_OFF_##ii_ss, CO_OD_LEN_##ii_ss, (uint32_t)(v))
#define CO_NODE_GET(node, ii_ss) co_node_get_at((node), CO_OD_OFF_##ii_ss, CO_OD_LEN_##ii_ss)
#define CO_NODE_GET_I(node, ii_ss) \
  co_node_get_i_at((node), CO_OD_OFF_##ii_ss, CO_OD_LEN_##ii_ss)
#define CO_NODE_PUT_F32(node, ii_ss, v) \
  (CO_NODE_LEN4_(ii_ss), co_node_put_f32_at((node), CO_OD_OFF_##ii_ss, (v)))
#define CO_NODE_GET_F32(node, ii_ss) \
  (CO_NODE_LEN4_(ii_ss), co_node_get_f32_at((node), CO_OD_OFF_##ii_ss))

/* Frame ring helpers (also used for the application's queues). */
void co_queue_init(co_queue_t *q);
co_status_t co_queue_push(co_queue_t *q, const fw_can_frame_t *frame);
bool co_queue_pop(co_queue_t *q, fw_can_frame_t *frame);

#ifdef __cplusplus
}
#endif
#endif /* PMLSM_CO_NODE_H */
