/**
 * @file co_internal.h
 * @brief Private to the CANopen slave (firmware_c/comm/src/co_*.c): what the
 *        service files share. Not installed, not part of the API.
 *
 * One file per CiA 301 service, all state in the caller-owned co_node_t:
 *   co_node.c  node core: frame rings, OD access, generic write/read with the
 *              communication-parameter rules, init, receive dispatch, process
 *   co_nmt.c   NMT slave: state machine, boot-up, reset node/communication
 *   co_sdo.c   SDO server: expedited + segmented download/upload, timeout
 *   co_pdo.c   PDO: mapping rules, RPDO (async/sync, deadline), TPDO (event/timer)
 *   co_sync.c  SYNC consumer, 0x1005 rule
 *   co_emcy.c  EMCY producer, 0x1014 rule
 *   co_hb.c    heartbeat producer (0x1017) and consumer (0x1016)
 */
#ifndef PMLSM_CO_INTERNAL_H
#define PMLSM_CO_INTERNAL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "pmlsm/co_node.h"

#define CO_COB_NMT 0x000u
#define CO_COB_SDO_TX 0x580u
#define CO_COB_SDO_RX 0x600u
#define CO_COB_HB 0x700u
#define CO_COB_INVALID 0x80000000u
#define CO_COB_EXT 0x20000000u

/* Internal functions are shared between the service files only: kept out of
   the symbol table of the shared libraries (the API stays co_node.h). */
#if defined(__GNUC__) && !defined(_WIN32)
#define CO_INTERNAL __attribute__((visibility("hidden")))
#else
#define CO_INTERNAL
#endif

/* ---- helpers (co_node.c) ----------------------------------------------- */

static inline void co_event(co_node_t *node, co_event_t ev, uint32_t arg) {
  if (node->cb.on_event != NULL) {
    node->cb.on_event(node->cb.ctx, ev, arg);
  }
}

static inline bool co_elapsed(uint32_t now, uint32_t since, uint32_t period_us) {
  return (uint32_t)(now - since) >= period_us;
}

static inline bool co_is_rpdo_comm(uint16_t i) {
  return i >= 0x1400u && i < 0x1400u + CO_OD_NR_RPDO;
}
static inline bool co_is_tpdo_comm(uint16_t i) {
  return i >= 0x1800u && i < 0x1800u + CO_OD_NR_TPDO;
}
static inline bool co_is_rpdo_map(uint16_t i) {
  return i >= 0x1600u && i < 0x1600u + CO_OD_NR_RPDO;
}
static inline bool co_is_tpdo_map(uint16_t i) {
  return i >= 0x1A00u && i < 0x1A00u + CO_OD_NR_TPDO;
}
/** 0x1010 store parameters / 0x1011 restore defaults, sub >= 1: commands. */
static inline bool co_is_store_cmd(uint16_t i, uint8_t sub) {
  return (i == 0x1010u || i == 0x1011u) && sub >= 1u;
}

/** Queue a frame for transmission (counted in count.tx_frames when queued). */
CO_INTERNAL void co_send(co_node_t *node, uint16_t id, uint8_t dlc, const uint8_t *data);
/** OD value of (index, sub) as u32; 0 when the object does not exist. */
CO_INTERNAL uint32_t co_get(const co_node_t *node, uint16_t index, uint8_t sub);

/* The PDO communication records 0x1400+n / 0x1800+n (n < 4) share one layout
 * in the OD RAM: sub ss of record n by compile-time handle (co_node.h), for the
 * per-period paths (RPDO/TPDO processing, SYNC) without a lookup. */
#define CO_RPDO_COMM_STRIDE (CO_OD_OFF_1401_00 - CO_OD_OFF_1400_00)
#define CO_TPDO_COMM_STRIDE (CO_OD_OFF_1801_00 - CO_OD_OFF_1800_00)
_Static_assert(CO_OD_NR_RPDO == 4u && CO_OD_NR_TPDO == 4u &&
    CO_OD_OFF_1401_01 == CO_OD_OFF_1400_01 + 1u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1401_01 == CO_OD_LEN_1400_01 &&
    CO_OD_OFF_1401_02 == CO_OD_OFF_1400_02 + 1u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1401_02 == CO_OD_LEN_1400_02 &&
    CO_OD_OFF_1401_05 == CO_OD_OFF_1400_05 + 1u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1401_05 == CO_OD_LEN_1400_05 &&
    CO_OD_OFF_1402_01 == CO_OD_OFF_1400_01 + 2u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1402_01 == CO_OD_LEN_1400_01 &&
    CO_OD_OFF_1402_02 == CO_OD_OFF_1400_02 + 2u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1402_02 == CO_OD_LEN_1400_02 &&
    CO_OD_OFF_1402_05 == CO_OD_OFF_1400_05 + 2u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1402_05 == CO_OD_LEN_1400_05 &&
    CO_OD_OFF_1403_01 == CO_OD_OFF_1400_01 + 3u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1403_01 == CO_OD_LEN_1400_01 &&
    CO_OD_OFF_1403_02 == CO_OD_OFF_1400_02 + 3u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1403_02 == CO_OD_LEN_1400_02 &&
    CO_OD_OFF_1403_05 == CO_OD_OFF_1400_05 + 3u * CO_RPDO_COMM_STRIDE &&
    CO_OD_LEN_1403_05 == CO_OD_LEN_1400_05 &&
    CO_OD_OFF_1801_01 == CO_OD_OFF_1800_01 + 1u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1801_01 == CO_OD_LEN_1800_01 &&
    CO_OD_OFF_1801_02 == CO_OD_OFF_1800_02 + 1u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1801_02 == CO_OD_LEN_1800_02 &&
    CO_OD_OFF_1801_03 == CO_OD_OFF_1800_03 + 1u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1801_03 == CO_OD_LEN_1800_03 &&
    CO_OD_OFF_1801_05 == CO_OD_OFF_1800_05 + 1u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1801_05 == CO_OD_LEN_1800_05 &&
    CO_OD_OFF_1802_01 == CO_OD_OFF_1800_01 + 2u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1802_01 == CO_OD_LEN_1800_01 &&
    CO_OD_OFF_1802_02 == CO_OD_OFF_1800_02 + 2u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1802_02 == CO_OD_LEN_1800_02 &&
    CO_OD_OFF_1802_03 == CO_OD_OFF_1800_03 + 2u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1802_03 == CO_OD_LEN_1800_03 &&
    CO_OD_OFF_1802_05 == CO_OD_OFF_1800_05 + 2u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1802_05 == CO_OD_LEN_1800_05 &&
    CO_OD_OFF_1803_01 == CO_OD_OFF_1800_01 + 3u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1803_01 == CO_OD_LEN_1800_01 &&
    CO_OD_OFF_1803_02 == CO_OD_OFF_1800_02 + 3u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1803_02 == CO_OD_LEN_1800_02 &&
    CO_OD_OFF_1803_03 == CO_OD_OFF_1800_03 + 3u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1803_03 == CO_OD_LEN_1800_03 &&
    CO_OD_OFF_1803_05 == CO_OD_OFF_1800_05 + 3u * CO_TPDO_COMM_STRIDE &&
    CO_OD_LEN_1803_05 == CO_OD_LEN_1800_05,
               "PDO communication records of one layout");
/* Likewise the mapping records 0x1600+n / 0x1A00+n: count (sub 0), then
 * subs 1..8, 4 bytes each, back to back. */
#define CO_RPDO_MAP_STRIDE (CO_OD_OFF_1601_00 - CO_OD_OFF_1600_00)
#define CO_TPDO_MAP_STRIDE (CO_OD_OFF_1A01_00 - CO_OD_OFF_1A00_00)
_Static_assert(
    CO_OD_OFF_1601_00 == CO_OD_OFF_1600_00 + 1u * CO_RPDO_MAP_STRIDE &&
    CO_OD_OFF_1601_08 == CO_OD_OFF_1600_08 + 1u * CO_RPDO_MAP_STRIDE &&
    CO_OD_OFF_1602_00 == CO_OD_OFF_1600_00 + 2u * CO_RPDO_MAP_STRIDE &&
    CO_OD_OFF_1602_08 == CO_OD_OFF_1600_08 + 2u * CO_RPDO_MAP_STRIDE &&
    CO_OD_OFF_1603_00 == CO_OD_OFF_1600_00 + 3u * CO_RPDO_MAP_STRIDE &&
    CO_OD_OFF_1603_08 == CO_OD_OFF_1600_08 + 3u * CO_RPDO_MAP_STRIDE &&
    CO_OD_LEN_1600_01 == 4u && CO_OD_OFF_1600_08 == CO_OD_OFF_1600_01 + 28u &&
    CO_OD_OFF_1A01_00 == CO_OD_OFF_1A00_00 + 1u * CO_TPDO_MAP_STRIDE &&
    CO_OD_OFF_1A01_08 == CO_OD_OFF_1A00_08 + 1u * CO_TPDO_MAP_STRIDE &&
    CO_OD_OFF_1A02_00 == CO_OD_OFF_1A00_00 + 2u * CO_TPDO_MAP_STRIDE &&
    CO_OD_OFF_1A02_08 == CO_OD_OFF_1A00_08 + 2u * CO_TPDO_MAP_STRIDE &&
    CO_OD_OFF_1A03_00 == CO_OD_OFF_1A00_00 + 3u * CO_TPDO_MAP_STRIDE &&
    CO_OD_OFF_1A03_08 == CO_OD_OFF_1A00_08 + 3u * CO_TPDO_MAP_STRIDE &&
    CO_OD_LEN_1A00_01 == 4u && CO_OD_OFF_1A00_08 == CO_OD_OFF_1A00_01 + 28u,
    "PDO mapping records of one layout");
/** Mapping count of PDO n (sub 0). */
#define CO_RPDO_MAP_COUNT(node, n) \
  co_node_get_at((node), (uint16_t)(CO_OD_OFF_1600_00 + (uint32_t)(n) * CO_RPDO_MAP_STRIDE), 1u)
#define CO_TPDO_MAP_COUNT(node, n) \
  co_node_get_at((node), (uint16_t)(CO_OD_OFF_1A00_00 + (uint32_t)(n) * CO_TPDO_MAP_STRIDE), 1u)
/** Mapping entry k (1..8) of PDO n. */
#define CO_RPDO_MAP(node, n, k)                                                       \
  co_node_get_at((node),                                                              \
                 (uint16_t)(CO_OD_OFF_1600_01 + (uint32_t)(n) * CO_RPDO_MAP_STRIDE +  \
                            4u * ((uint32_t)(k) - 1u)),                               \
                 4u)
#define CO_TPDO_MAP(node, n, k)                                                       \
  co_node_get_at((node),                                                              \
                 (uint16_t)(CO_OD_OFF_1A00_01 + (uint32_t)(n) * CO_TPDO_MAP_STRIDE +  \
                            4u * ((uint32_t)(k) - 1u)),                               \
                 4u)
#define CO_RPDO_COMM(node, n, ss)                                                   \
  co_node_get_at((node), (uint16_t)(CO_OD_OFF_1400_##ss + (uint32_t)(n) * CO_RPDO_COMM_STRIDE), \
                 CO_OD_LEN_1400_##ss)
#define CO_TPDO_COMM(node, n, ss)                                                   \
  co_node_get_at((node), (uint16_t)(CO_OD_OFF_1800_##ss + (uint32_t)(n) * CO_TPDO_COMM_STRIDE), \
                 CO_OD_LEN_1800_##ss)
/** Checked write of OD position pos (SDO download, RPDO); from_pdo skips the
 *  communication-parameter rules. Returns the abort code. */
CO_INTERNAL co_abort_t co_write_pos(co_node_t *node, uint16_t pos, const uint8_t *data,
                                    size_t len, bool from_pdo);

/* ---- NMT (co_nmt.c) ------------------------------------------------------ */

/** Reset the communication run-time state, send the boot-up, enter PRE-OPERATIONAL. */
CO_INTERNAL void co_boot(co_node_t *node);
/** NMT command frame (COB-ID 0). */
CO_INTERNAL void co_nmt_frame(co_node_t *node, const fw_can_frame_t *f);

/* ---- SDO server (co_sdo.c) ----------------------------------------------- */

/** SDO request frame (COB-ID 0x600 + node id). */
CO_INTERNAL void co_sdo_frame(co_node_t *node, const fw_can_frame_t *f);
/** Abort a segmented transfer idle for CO_SDO_TIMEOUT_US. */
CO_INTERNAL void co_sdo_check_timeout(co_node_t *node, uint32_t now_us);

/* ---- PDO (co_pdo.c) ---------------------------------------------------------- */

/** CiA 301 rules for the PDO communication (0x1400/0x1800) and mapping
 *  (0x1600/0x1A00) parameters; CO_ABORT_NONE for any other index. */
CO_INTERNAL co_abort_t co_pdo_check_config(const co_node_t *node, uint16_t index, uint8_t sub,
                                           uint32_t v);
/** Apply RPDO n's data to the mapped objects. */
CO_INTERNAL void co_rpdo_apply(co_node_t *node, uint8_t n, const uint8_t *data, uint8_t dlc);
/** Pack TPDO n into data; returns the length in bytes. */
CO_INTERNAL uint8_t co_tpdo_pack(const co_node_t *node, uint8_t n, uint8_t data[8]);
/** Send TPDO n and remember what was sent. */
CO_INTERNAL void co_tpdo_send(co_node_t *node, uint8_t n, const uint8_t *data, uint8_t len);
/** A frame matching a valid RPDO: stored for the next SYNC or applied. False: no RPDO. */
CO_INTERNAL bool co_rpdo_frame(co_node_t *node, const fw_can_frame_t *f);
/** RPDO deadline monitoring (0x1400+n:5). */
CO_INTERNAL void co_rpdo_check(co_node_t *node, uint32_t now_us);
/** Event-driven TPDOs (transmission type 254/255: change, inhibit time, event timer). */
CO_INTERNAL void co_tpdo_process(co_node_t *node, uint32_t now_us);

/* ---- SYNC (co_sync.c) ------------------------------------------------------ */

/** A SYNC was received. */
CO_INTERNAL void co_sync(co_node_t *node);
/** CiA 301 rule for 0x1005 (COB-ID SYNC). */
CO_INTERNAL co_abort_t co_sync_check_config(uint32_t v);

/* ---- EMCY (co_emcy.c) -------------------------------------------------------- */

/** CiA 301 rules for 0x1014 (COB-ID EMCY). */
CO_INTERNAL co_abort_t co_emcy_check_config(const co_node_t *node, uint32_t v);

/* ---- heartbeat (co_hb.c) ------------------------------------------------------ */

/** Heartbeat (or boot-up) frame of another node (COB-ID 0x701..0x77F). */
CO_INTERNAL void co_hb_frame(co_node_t *node, const fw_can_frame_t *f);
/** Heartbeat consumer timeouts (0x1016). */
CO_INTERNAL void co_hb_check(co_node_t *node, uint32_t now_us);
/** Heartbeat producer (0x1017). */
CO_INTERNAL void co_hb_produce(co_node_t *node, uint32_t now_us);
/** CiA 301 rules for 0x1016 sub 1..CO_HB_CONSUMERS (heartbeat consumers). */
CO_INTERNAL co_abort_t co_hb_check_config(const co_node_t *node, uint8_t sub, uint32_t v);

#endif /* PMLSM_CO_INTERNAL_H */
