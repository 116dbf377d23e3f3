/**
 * @file fw_app_internal.h
 * @brief What the drive application's sources (fw_app.c, fw_app_od.c, fw_nvm.c,
 *        fw_trace.c)
 *        share, and nothing else includes.
 */
#ifndef PMLSM_FW_APP_INTERNAL_H
#define PMLSM_FW_APP_INTERNAL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "pmlsm/fw_app.h"

/** CiA 402 modes of operation (0x6060, 0x6061) the drive has. */
#define FW_APP_MODE_CSV 9
#define FW_APP_MODE_CST 10

/* ---- fw_app.c ---- */

/** Complete every published period not processed yet (before the core's
 *  configuration changes: completed with the configuration they ran with). */
void fw_app_complete_pending(fw_app_t *app);
/** The lock of the background's core changes (fw_app_attach_lock): enter ... */
uint32_t fw_app_lock(fw_app_t *app);
/** ... and exit. */
void fw_app_unlock(fw_app_t *app, uint32_t key);

/** (Re)start the core with cfg (fw_init): the published periods completed first
 *  with the configuration they ran with, the time base converted up to now at the
 *  old rate, then the new PWM rate taken. Returns the fw_init status. */
fw_status_t fw_app_start_core(fw_app_t *app, const fw_config_t *cfg);
/** One frame of the serial link into the UART ring (counted when dropped). */
void fw_app_send_frame(fw_app_t *app, uint8_t type, const uint8_t *payload, size_t len);

/* ---- fw_app_od.c ---- */

/** The OD's objects the drive sets itself (storage support, version, build, board)
 *  and the configuration's views. */
void fw_app_sync_static_od(fw_app_t *app);
/** A core status as an SDO abort code. */
co_abort_t fw_app_status_abort(fw_status_t st);
/** A write of an object without a hook: a view of a fw_config_t field
 *  (co_od_cfg_links) changes the core's configuration; others, nothing. Inside
 *  the lock. */
co_abort_t fw_app_write_config(fw_app_t *app, uint16_t index, uint8_t sub, uint32_t v);
/** The OD's actual values from the newest published period. */
void fw_app_update_od(fw_app_t *app, const fw_app_period_t *p);
/** An EMCY when a published period's fault code changed. */
void fw_app_emcy(fw_app_t *app, const fw_snapshot_t *s);

/* ---- fw_nvm.c ---- */

/** Boot from the stored block: configuration and objects (comm_only: the
 *  communication objects alone, for NMT reset communication). Returns true
 *  when it started the core with the stored configuration. */
bool fw_app_nvm_boot(fw_app_t *app, bool comm_only);

/* ---- fw_trace.c ---- */

/** A published period for the trace: its sample, and one upload frame when
 *  uploading and the UART ring has room. */
void fw_app_trace_period(fw_app_t *app, const fw_snapshot_t *s);

#endif /* PMLSM_FW_APP_INTERNAL_H */
