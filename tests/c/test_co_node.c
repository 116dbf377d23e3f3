/**
 * @file test_co_node.c
 * @brief CANopen slave: NMT, SDO (expedited, segmented, abort codes), PDO
 *        mapping by SDO, RPDO/TPDO (SYNC and event driven), heartbeat
 *        producer/consumer, EMCY, queues.
 */
#include <string.h>

#include "pmlsm/co_node.h"
#include "tinytest.h"

#define NID 5u

static co_node_t g_node; /* test fixture only (the library has no globals) */

typedef struct {
  int hb_lost;
  int hb_resumed;
  int rpdo;
  int resets;
  int rpdo_timeout;
  uint32_t rpdo_timeout_arg;
  uint32_t refuse_index; /* write hook refuses this index */
} hooks_t;

static hooks_t g_hooks;

static co_abort_t on_write(void *ctx, uint16_t index, uint8_t sub, const uint8_t *d, size_t n) {
  hooks_t *h = (hooks_t *)ctx;
  (void)sub;
  (void)d;
  (void)n;
  return index == h->refuse_index ? CO_ABORT_DEVICE_STATE : CO_ABORT_NONE;
}

static void on_event(void *ctx, co_event_t ev, uint32_t arg) {
  hooks_t *h = (hooks_t *)ctx;
  (void)arg;
  if (ev == CO_EV_HB_LOST) h->hb_lost++;
  if (ev == CO_EV_HB_RESUMED) h->hb_resumed++;
  if (ev == CO_EV_RPDO) h->rpdo++;
  if (ev == CO_EV_RESET_NODE) h->resets++;
  if (ev == CO_EV_RPDO_TIMEOUT) {
    h->rpdo_timeout++;
    h->rpdo_timeout_arg = arg;
  }
}

static void drain(void) {
  fw_can_frame_t f;
  while (co_node_tx_pop(&g_node, &f)) {
  }
}

static void setup(void) {
  memset(&g_hooks, 0, sizeof g_hooks);
  co_callbacks_t cb = {&g_hooks, on_write, on_event};
  co_node_init(&g_node, NID, &cb);
  drain();
}

static void rx(uint16_t id, uint8_t dlc, const uint8_t *d) {
  fw_can_frame_t f;
  memset(&f, 0, sizeof f);
  f.id = id;
  f.dlc = dlc;
  if (d) memcpy(f.data, d, dlc);
  co_node_rx_isr(&g_node, &f);
}

static void nmt(uint8_t cs) {
  uint8_t d[2] = {cs, 0};
  rx(0x000, 2, d);
  co_node_process_rx(&g_node, 0);
}

/* Send one SDO request, return the response (false if none). */
static int sdo(const uint8_t req[8], uint8_t resp[8]) {
  fw_can_frame_t f;
  rx((uint16_t)(0x600 + NID), 8, req);
  co_node_process_rx(&g_node, 0);
  while (co_node_tx_pop(&g_node, &f)) {
    if (f.id == 0x580 + NID) {
      memcpy(resp, f.data, 8);
      return 1;
    }
  }
  return 0;
}

static uint32_t abort_code(const uint8_t r[8]) {
  return r[0] == 0x80 ? (uint32_t)(r[4] | (r[5] << 8) | (r[6] << 16) | ((uint32_t)r[7] << 24))
                      : 0u;
}

/* Expedited download; returns 0 or the abort code. */
static uint32_t sdo_write(uint16_t idx, uint8_t sub, uint32_t v, uint8_t n) {
  uint8_t req[8] = {(uint8_t)(0x23 | ((4 - n) << 2)), (uint8_t)idx, (uint8_t)(idx >> 8), sub,
                    (uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)(v >> 24)};
  uint8_t r[8];
  if (!sdo(req, r)) return 0xFFFFFFFFu;
  if (r[0] == 0x60) return 0;
  return abort_code(r);
}

/* Expedited upload; returns 0 or the abort code. */
static uint32_t sdo_read(uint16_t idx, uint8_t sub, uint32_t *v) {
  uint8_t req[8] = {0x40, (uint8_t)idx, (uint8_t)(idx >> 8), sub, 0, 0, 0, 0};
  uint8_t r[8];
  if (!sdo(req, r)) return 0xFFFFFFFFu;
  if ((r[0] & 0xE3) == 0x43) {
    *v = (uint32_t)(r[4] | (r[5] << 8) | (r[6] << 16) | ((uint32_t)r[7] << 24));
    return 0;
  }
  return r[0] == 0x41 ? 0xEEEEEEEEu : abort_code(r);
}

static void test_boot_and_nmt(void) {
  fw_can_frame_t f;
  co_callbacks_t cb = {&g_hooks, on_write, on_event};
  TT_CHECK(co_node_init(&g_node, 0, &cb) == CO_ERR_ARG);
  TT_CHECK(co_node_init(&g_node, 128, &cb) == CO_ERR_ARG);
  TT_CHECK(co_node_init(NULL, 5, &cb) == CO_ERR_NULL);
  co_node_init(&g_node, NID, &cb);
  TT_CHECK(co_node_tx_pop(&g_node, &f));
  TT_CHECK(f.id == 0x700 + NID && f.dlc == 1 && f.data[0] == 0x00);
  TT_CHECK(co_node_nmt(&g_node) == CO_NMT_PRE_OPERATIONAL);
  nmt(0x01);
  TT_CHECK(co_node_nmt(&g_node) == CO_NMT_OPERATIONAL);
  nmt(0x02);
  TT_CHECK(co_node_nmt(&g_node) == CO_NMT_STOPPED);
  /* SDO ignored when stopped */
  uint8_t req[8] = {0x40, 0x00, 0x10, 0, 0, 0, 0, 0}, r[8];
  TT_CHECK(!sdo(req, r));
  nmt(0x80);
  TT_CHECK(co_node_nmt(&g_node) == CO_NMT_PRE_OPERATIONAL);
  /* other node id: ignored */
  uint8_t d[2] = {0x01, 9};
  rx(0, 2, d);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(co_node_nmt(&g_node) == CO_NMT_PRE_OPERATIONAL);
  /* reset node: defaults back, boot-up again */
  TT_CHECK(sdo_write(0x1017, 0, 500, 2) == 0);
  nmt(0x81);
  TT_CHECK(g_hooks.resets == 1);
  uint32_t v = 0;
  TT_CHECK(sdo_read(0x1017, 0, &v) == 0 && v == 100);
  TT_CHECK(co_node_nmt(&g_node) == CO_NMT_PRE_OPERATIONAL);
}

static void test_sdo_expedited(void) {
  uint32_t v = 0;
  setup();
  TT_CHECK(sdo_read(0x1000, 0, &v) == 0 && v == 0x00020192u);
  TT_CHECK(sdo_read(0x1018, 0, &v) == 0 && v == 4);
  TT_CHECK(sdo_read(0x1014, 0, &v) == 0 && v == 0x80u + NID);
  TT_CHECK(sdo_read(0x1800, 1, &v) == 0 && v == 0x180u + NID);
  TT_CHECK(sdo_write(0x6040, 0, 0x0006, 2) == 0);
  TT_CHECK(sdo_read(0x6040, 0, &v) == 0 && v == 6);
  TT_CHECK(sdo_write(0x60FF, 0, (uint32_t)-12345, 4) == 0);
  TT_CHECK(sdo_read(0x60FF, 0, &v) == 0 && (int32_t)v == -12345);
  /* size not indicated (0x22): object size is used */
  uint8_t req[8] = {0x22, 0x40, 0x60, 0, 0x0F, 0, 0, 0}, r[8];
  TT_CHECK(sdo(req, r) && r[0] == 0x60);
  TT_CHECK(sdo_read(0x6040, 0, &v) == 0 && v == 0x0F);
}

static void test_sdo_aborts(void) {
  uint32_t v = 0;
  setup();
  TT_CHECK(sdo_read(0x1234, 0, &v) == 0x06020000u);
  TT_CHECK(sdo_write(0x1234, 0, 1, 1) == 0x06020000u);
  TT_CHECK(sdo_read(0x1018, 9, &v) == 0x06090011u);
  TT_CHECK(sdo_write(0x1018, 9, 1, 4) == 0x06090011u);
  TT_CHECK(sdo_write(0x6041, 0, 1, 2) == 0x06010002u);  /* statusword ro */
  TT_CHECK(sdo_write(0x1000, 0, 1, 4) == 0x06010002u);  /* const */
  TT_CHECK(sdo_write(0x6060, 0, 11, 1) == 0x06090031u); /* mode too high */
  TT_CHECK(sdo_write(0x6060, 0, 8, 1) == 0x06090032u);  /* mode too low */
  TT_CHECK(sdo_write(0x6071, 0, (uint16_t)1001, 2) == 0x06090031u);
  TT_CHECK(sdo_write(0x6071, 0, (uint16_t)-1001, 2) == 0x06090032u);
  TT_CHECK(sdo_read(0x6060, 0, &v) == 0 && v == 9); /* unchanged */
  TT_CHECK(sdo_write(0x6040, 0, 1, 4) == 0x06070010u); /* u16 written with 4 bytes */
  TT_CHECK(sdo_write(0x1017, 0, 1, 1) == 0x06070010u);
  TT_CHECK(sdo_write(0x1005, 0, 0x40000080u, 4) == 0x06090030u); /* SYNC producer */
  /* REAL32 limits and NaN */
  float f = 5.0f;
  uint32_t raw;
  memcpy(&raw, &f, 4);
  TT_CHECK(sdo_write(0x2001, 0, raw, 4) == 0x06090031u);
  f = 0.0f;
  memcpy(&raw, &f, 4);
  TT_CHECK(sdo_write(0x2001, 0, raw, 4) == 0x06090032u);
  TT_CHECK(sdo_write(0x2001, 0, 0x7FC00000u, 4) == 0x06090030u);
  f = 0.7f;
  memcpy(&raw, &f, 4);
  TT_CHECK(sdo_write(0x2001, 0, raw, 4) == 0);
  /* block transfer / invalid ccs */
  uint8_t req[8] = {0xC0, 0x00, 0x10, 0, 0, 0, 0, 0}, r[8];
  TT_CHECK(sdo(req, r) && abort_code(r) == 0x05040001u);
  req[0] = 0xE0;
  TT_CHECK(sdo(req, r) && abort_code(r) == 0x05040001u);
  /* segment without a transfer */
  req[0] = 0x60;
  TT_CHECK(sdo(req, r) && abort_code(r) == 0x05040001u);
  req[0] = 0x00;
  TT_CHECK(sdo(req, r) && abort_code(r) == 0x05040001u);
  /* write hook refuses */
  g_hooks.refuse_index = 0x6040;
  TT_CHECK(sdo_write(0x6040, 0, 0x1F, 2) == 0x08000022u);
  TT_CHECK(sdo_read(0x6040, 0, &v) == 0 && v == 0);
  /* wrong DLC: ignored */
  fw_can_frame_t out;
  uint8_t d[8] = {0x40, 0x00, 0x10, 0, 0, 0, 0, 0};
  rx((uint16_t)(0x600 + NID), 4, d);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(!co_node_tx_pop(&g_node, &out));
  TT_CHECK(g_node.count.sdo_aborts >= 10);
}

static void test_sdo_segmented_upload(void) {
  setup();
  uint8_t req[8] = {0x40, 0x08, 0x10, 0, 0, 0, 0, 0}, r[8];
  TT_CHECK(sdo(req, r));
  TT_CHECK(r[0] == 0x41);
  uint32_t size = (uint32_t)(r[4] | (r[5] << 8));
  TT_CHECK(size == strlen("PMLSM sensorless drive"));
  char buf[64] = {0};
  size_t got = 0;
  uint8_t t = 0;
  for (int k = 0; k < 10; k++) {
    uint8_t seg[8] = {(uint8_t)(0x60 | (t << 4)), 0, 0, 0, 0, 0, 0, 0};
    TT_CHECK(sdo(seg, r));
    TT_CHECK((r[0] >> 5) == 0 && ((r[0] >> 4) & 1) == t);
    size_t n = 7u - ((r[0] >> 1) & 7u);
    memcpy(buf + got, &r[1], n);
    got += n;
    t ^= 1;
    if (r[0] & 1) break;
  }
  TT_CHECK(got == size);
  TT_CHECK(strcmp(buf, "PMLSM sensorless drive") == 0);
  /* toggle error */
  TT_CHECK(sdo(req, r) && r[0] == 0x41);
  uint8_t bad[8] = {0x70, 0, 0, 0, 0, 0, 0, 0};
  TT_CHECK(sdo(bad, r) && abort_code(r) == 0x05030000u);
  /* empty string: segmented with size 0 */
  uint8_t req2[8] = {0x40, 0x42, 0x20, 0, 0, 0, 0, 0};
  TT_CHECK(sdo(req2, r) && r[0] == 0x41 && r[4] == 0);
  uint8_t seg[8] = {0x60, 0, 0, 0, 0, 0, 0, 0};
  TT_CHECK(sdo(seg, r) && r[0] == (0x00 | (7 << 1) | 1));
}

static void test_sdo_segmented_download(void) {
  setup();
  const char *txt = "axis-1 left rail"; /* 16 bytes */
  uint8_t init[8] = {0x21, 0x42, 0x20, 0, 16, 0, 0, 0}, r[8];
  TT_CHECK(sdo(init, r) && r[0] == 0x60);
  size_t sent = 0;
  uint8_t t = 0;
  while (sent < 16) {
    size_t n = 16 - sent > 7 ? 7 : 16 - sent;
    uint8_t seg[8] = {0};
    int last = sent + n == 16;
    seg[0] = (uint8_t)((t << 4) | ((7 - n) << 1) | (last ? 1 : 0));
    memcpy(&seg[1], txt + sent, n);
    TT_CHECK(sdo(seg, r) && r[0] == (0x20 | (t << 4)));
    sent += n;
    t ^= 1;
  }
  uint8_t buf[32];
  size_t len = sizeof buf;
  TT_CHECK(co_node_read(&g_node, 0x2042, 0, buf, &len) == CO_ABORT_NONE);
  TT_CHECK(len == 16 && memcmp(buf, txt, 16) == 0);
  /* too long for the object */
  uint8_t init2[8] = {0x21, 0x42, 0x20, 0, 40, 0, 0, 0};
  TT_CHECK(sdo(init2, r) && abort_code(r) == 0x06070010u);
  /* size indicated 10 but 7 sent with c=1 */
  uint8_t init3[8] = {0x21, 0x42, 0x20, 0, 10, 0, 0, 0};
  TT_CHECK(sdo(init3, r) && r[0] == 0x60);
  uint8_t seg[8] = {0x01, 'a', 'b', 'c', 'd', 'e', 'f', 'g'};
  TT_CHECK(sdo(seg, r) && abort_code(r) == 0x06070010u);
  /* toggle error */
  TT_CHECK(sdo(init3, r) && r[0] == 0x60);
  uint8_t seg2[8] = {0x10, 'a', 'b', 'c', 'd', 'e', 'f', 'g'};
  TT_CHECK(sdo(seg2, r) && abort_code(r) == 0x05030000u);
  /* read-only object */
  uint8_t init4[8] = {0x21, 0x08, 0x10, 0, 10, 0, 0, 0};
  TT_CHECK(sdo(init4, r) && abort_code(r) == 0x06010002u);
  /* timeout */
  TT_CHECK(sdo(init3, r) && r[0] == 0x60);
  co_node_process_tx(&g_node, 2000000u);
  fw_can_frame_t f;
  int seen = 0;
  while (co_node_tx_pop(&g_node, &f)) {
    if (f.id == 0x580 + NID && f.data[0] == 0x80) {
      seen = abort_code(f.data) == 0x05040000u;
    }
  }
  TT_CHECK(seen);
}

static void test_pdo_remap_and_rpdo(void) {
  setup();
  uint32_t v;
  /* mapping a valid PDO is refused */
  TT_CHECK(sdo_write(0x1600, 0, 0, 1) == 0x06010000u);
  /* CiA 301 procedure on RPDO1: disable, count 0, entries, count, enable */
  TT_CHECK(sdo_write(0x1400, 1, 0x80000000u | (0x200 + NID), 4) == 0);
  TT_CHECK(sdo_write(0x1600, 1, 0x60600008, 4) == 0x06010000u); /* count != 0 */
  TT_CHECK(sdo_write(0x1600, 0, 0, 1) == 0);
  TT_CHECK(sdo_write(0x1600, 1, 0x60400010, 4) == 0);
  TT_CHECK(sdo_write(0x1600, 2, 0x60710010, 4) == 0);
  TT_CHECK(sdo_write(0x1600, 3, 0x60600008, 4) == 0);
  TT_CHECK(sdo_write(0x1600, 4, 0x60410010, 4) == 0x06040041u); /* ro in RPDO */
  TT_CHECK(sdo_write(0x1600, 4, 0x10080000 | 0xB8, 4) == 0x06040041u); /* not mappable */
  TT_CHECK(sdo_write(0x1600, 4, 0x12340010, 4) == 0x06020000u);
  TT_CHECK(sdo_write(0x1600, 4, 0x60400020, 4) == 0x06040042u); /* wrong length */
  TT_CHECK(sdo_write(0x1600, 0, 9, 1) == 0x06090031u);
  TT_CHECK(sdo_write(0x1600, 0, 3, 1) == 0);
  TT_CHECK(sdo_write(0x1400, 1, 0x200 + NID, 4) == 0);
  /* changing the COB-ID of a valid PDO is refused */
  TT_CHECK(sdo_write(0x1400, 1, 0x222, 4) == 0x06090030u);
  TT_CHECK(sdo_write(0x1400, 2, 245, 1) == 0x06090030u);
  /* RPDO ignored in PRE-OPERATIONAL */
  uint8_t d[5] = {0x0F, 0x00, 0xF4, 0x01, 10}; /* cw 0x0F, torque 500, mode 10 */
  rx((uint16_t)(0x200 + NID), 5, d);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(sdo_read(0x6040, 0, &v) == 0 && v == 0);
  nmt(0x01);
  rx((uint16_t)(0x200 + NID), 5, d);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(g_hooks.rpdo == 1);
  TT_CHECK(co_node_get_u32(&g_node, CO_OD_6040_00) == 0x0F);
  TT_CHECK(co_node_get_i32(&g_node, CO_OD_6071_00) == 500);
  TT_CHECK(co_node_get_i32(&g_node, CO_OD_6060_00) == 10);
  /* too short: ignored, counted */
  rx((uint16_t)(0x200 + NID), 3, d);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(g_node.count.rpdo_errors == 1);
  /* out-of-range value in an RPDO is not stored */
  uint8_t d2[5] = {0x07, 0x00, 0xF4, 0x01, 3};
  rx((uint16_t)(0x200 + NID), 5, d2);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(co_node_get_i32(&g_node, CO_OD_6060_00) == 10);
  TT_CHECK(co_node_get_u32(&g_node, CO_OD_6040_00) == 0x07);
  /* synchronous RPDO: applied at the next SYNC */
  TT_CHECK(sdo_write(0x1401, 2, 1, 1) == 0);
  uint8_t d3[4] = {0x06, 0x00, 0x10, 0x00};
  rx((uint16_t)(0x300 + NID), 4, d3);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(co_node_get_i32(&g_node, CO_OD_6071_00) == 500);
  rx(0x80, 0, NULL);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(co_node_get_i32(&g_node, CO_OD_6071_00) == 16);
}

static int count_id(uint16_t id, fw_can_frame_t *last) {
  fw_can_frame_t f;
  int n = 0;
  while (co_node_tx_pop(&g_node, &f)) {
    if (f.id == id) {
      n++;
      if (last) *last = f;
    }
  }
  return n;
}

static void test_tpdo(void) {
  fw_can_frame_t f;
  setup();
  nmt(0x01);
  drain();
  /* TPDO2 (type 1): every SYNC; position + velocity */
  co_node_set_i32(&g_node, CO_OD_6064_00, 123456);
  co_node_set_i32(&g_node, CO_OD_606C_00, -42);
  rx(0x80, 0, NULL);
  co_node_process_rx(&g_node, 1000);
  TT_CHECK(count_id((uint16_t)(0x280 + NID), &f) == 1);
  TT_CHECK(f.dlc == 8);
  TT_CHECK((int32_t)(f.data[0] | (f.data[1] << 8) | (f.data[2] << 16) |
                     ((uint32_t)f.data[3] << 24)) == 123456);
  TT_CHECK((int32_t)(f.data[4] | (f.data[5] << 8) | (f.data[6] << 16) |
                     ((uint32_t)f.data[7] << 24)) == -42);
  /* every 3rd SYNC */
  TT_CHECK(sdo_write(0x1801, 2, 3, 1) == 0);
  drain();
  int n = 0;
  for (int k = 0; k < 9; k++) {
    rx(0x80, 0, NULL);
    co_node_process_rx(&g_node, 1000);
    n += count_id((uint16_t)(0x280 + NID), NULL);
  }
  TT_CHECK(n == 3);
  /* TPDO1 event driven: on change, inhibit 1 ms, event timer 100 ms */
  co_node_process_tx(&g_node, 0);
  drain();
  co_node_set_u32(&g_node, CO_OD_6041_00, 0x0237);
  co_node_process_tx(&g_node, 100000);
  TT_CHECK(count_id((uint16_t)(0x180 + NID), &f) == 1);
  TT_CHECK(f.dlc == 3 && f.data[0] == 0x37 && f.data[1] == 0x02);
  co_node_set_u32(&g_node, CO_OD_6041_00, 0x0233);
  co_node_process_tx(&g_node, 100500); /* within inhibit time */
  TT_CHECK(count_id((uint16_t)(0x180 + NID), NULL) == 0);
  co_node_process_tx(&g_node, 101000);
  TT_CHECK(count_id((uint16_t)(0x180 + NID), NULL) == 1);
  co_node_process_tx(&g_node, 150000); /* no change, timer not expired */
  TT_CHECK(count_id((uint16_t)(0x180 + NID), NULL) == 0);
  co_node_process_tx(&g_node, 201000); /* event timer */
  TT_CHECK(count_id((uint16_t)(0x180 + NID), NULL) == 1);
  /* TPDO4 (by default the drive time and the reference sensor, every SYNC): a
     valid PDO's mapping cannot change (CiA 301), so disable it, remap it to the
     estimator and enable it again */
  TT_CHECK(sdo_write(0x1A03, 0, 0, 1) == 0x06010000u); /* unsupported access */
  TT_CHECK(sdo_write(0x1803, 1, 0x80000000u | (0x480 + NID), 4) == 0);
  TT_CHECK(sdo_write(0x1A03, 0, 0, 1) == 0);
  TT_CHECK(sdo_write(0x1A03, 1, 0x20200120, 4) == 0);
  TT_CHECK(sdo_write(0x1A03, 2, 0x20200220, 4) == 0);
  TT_CHECK(sdo_write(0x1A03, 3, 0x20200508, 4) == 0x06040042u);
  TT_CHECK(sdo_write(0x1A03, 3, 0x20200820, 4) == 0x06040042u);
  TT_CHECK(sdo_write(0x1A03, 0, 2, 1) == 0);
  TT_CHECK(sdo_write(0x1803, 2, 1, 1) == 0);
  TT_CHECK(sdo_write(0x1803, 1, 0x480 + NID, 4) == 0);
  co_node_set_f32(&g_node, CO_OD_2020_01, 1.5f);
  drain();
  rx(0x80, 0, NULL);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(count_id((uint16_t)(0x480 + NID), &f) == 1);
  float ang;
  memcpy(&ang, f.data, 4);
  TT_CHECK_NEAR(ang, 1.5, 0.0);
  /* over 64 bits refused */
  TT_CHECK(sdo_write(0x1803, 1, 0x80000000u | (0x480 + NID), 4) == 0);
  TT_CHECK(sdo_write(0x1A03, 0, 0, 1) == 0);
  TT_CHECK(sdo_write(0x1A03, 3, 0x20200320, 4) == 0);
  TT_CHECK(sdo_write(0x1A03, 0, 3, 1) == 0x06040042u);
  /* no TPDO when pre-operational */
  nmt(0x80);
  drain();
  rx(0x80, 0, NULL);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(count_id((uint16_t)(0x280 + NID), NULL) == 0);
}

static void test_heartbeat(void) {
  fw_can_frame_t f;
  setup();
  /* producer: 100 ms default */
  co_node_process_tx(&g_node, 50000);
  TT_CHECK(count_id((uint16_t)(0x700 + NID), NULL) == 0);
  co_node_process_tx(&g_node, 100000);
  TT_CHECK(count_id((uint16_t)(0x700 + NID), &f) == 1);
  TT_CHECK(f.data[0] == 0x7F);
  /* consumer: node 1, 50 ms */
  TT_CHECK(sdo_write(0x1016, 1, (1u << 16) | 50u, 4) == 0);
  co_node_process_tx(&g_node, 1000000); /* not started before the first heartbeat */
  TT_CHECK(g_hooks.hb_lost == 0);
  uint8_t st = 0x05;
  rx(0x701, 1, &st);
  co_node_process_rx(&g_node, 1000000);
  co_node_process_tx(&g_node, 1040000);
  TT_CHECK(g_hooks.hb_lost == 0);
  rx(0x701, 1, &st);
  co_node_process_rx(&g_node, 1040000);
  co_node_process_tx(&g_node, 1089000);
  TT_CHECK(g_hooks.hb_lost == 0);
  co_node_process_tx(&g_node, 1091000);
  TT_CHECK(g_hooks.hb_lost == 1);
  co_node_process_tx(&g_node, 1200000);
  TT_CHECK(g_hooks.hb_lost == 1); /* reported once */
  rx(0x701, 1, &st);
  co_node_process_rx(&g_node, 1300000);
  TT_CHECK(g_hooks.hb_resumed == 1);
  /* other node ids do not feed the consumer */
  co_node_process_tx(&g_node, 1400000);
  TT_CHECK(g_hooks.hb_lost == 2);
}

/* CiA 301: 0x1014 bits 0-29 fixed while valid; 0x1016 one entry per node id. */
static void test_comm_write_rules(void) {
  setup();
  uint32_t emcy = 0x80u + NID;
  TT_CHECK(sdo_write(0x1014, 0, emcy, 4) == 0);
  TT_CHECK(sdo_write(0x1014, 0, emcy + 1u, 4) == 0x06090030u);
  TT_CHECK(sdo_write(0x1014, 0, 0x80000000u | (emcy + 1u), 4) == 0x06090030u);
  TT_CHECK(sdo_write(0x1014, 0, 0x20000000u | emcy, 4) == 0x06090030u);
  TT_CHECK(co_node_get_u32(&g_node, CO_OD_1014_00) == emcy);
  TT_CHECK(sdo_write(0x1014, 0, 0x80000000u | emcy, 4) == 0);
  TT_CHECK(sdo_write(0x1014, 0, 0x80000000u | 0x91u, 4) == 0);
  TT_CHECK(sdo_write(0x1014, 0, 0x91u, 4) == 0);
  TT_CHECK(sdo_write(0x1014, 0, 0u, 4) == 0x06090030u); /* valid id 0 */
  TT_CHECK(co_node_emcy(&g_node, 0x8130, 0x11, NULL) == CO_OK);
  TT_CHECK(count_id(0x91u, NULL) == 1); /* the new COB-ID is used */
  TT_CHECK(sdo_write(0x1016, 1, (0x7Eu << 16) | 200u, 4) == 0);
  TT_CHECK(sdo_write(0x1016, 2, (0x7Eu << 16) | 300u, 4) == 0x06040043u);
  TT_CHECK(co_node_get_u32(&g_node, CO_OD_1016_02) == 0u);
  TT_CHECK(sdo_write(0x1016, 2, 0x7Eu << 16, 4) == 0);       /* unused entry */
  TT_CHECK(sdo_write(0x1016, 2, (0x10u << 16) | 300u, 4) == 0);
  TT_CHECK(sdo_write(0x1016, 1, (0x10u << 16) | 100u, 4) == 0x06040043u);
  TT_CHECK(sdo_write(0x1016, 1, (0x7Eu << 16) | 250u, 4) == 0); /* same entry */
  TT_CHECK(sdo_write(0x1016, 1, (0x80u << 16) | 250u, 4) == 0x06090030u); /* id > 127 */
}

/* A heartbeat timeout is reported by process_rx already (before the
 * application's control step), not only by process_tx. */
static void test_heartbeat_timeout_seen_in_rx(void) {
  setup();
  TT_CHECK(sdo_write(0x1016, 1, (1u << 16) | 50u, 4) == 0);
  uint8_t st = 0x05;
  rx(0x701, 1, &st);
  co_node_process_rx(&g_node, 1000000);
  co_node_process_rx(&g_node, 1049999);
  TT_CHECK(g_hooks.hb_lost == 0);
  co_node_process_rx(&g_node, 1050000);
  TT_CHECK(g_hooks.hb_lost == 1);
}

/* RPDO event timer 0x1400:5 as a deadline: armed by the first applied RPDO
 * in OPERATIONAL, reported once, re-armed by fresh data; for a synchronous
 * RPDO the deadline counts applications (SYNC), not receptions. */
static void test_rpdo_deadline(void) {
  uint8_t d[6] = {0x0F, 0x00, 0x10, 0x00, 0x00, 0x00};
  setup();
  TT_CHECK(sdo_write(0x1400, 5, 20u, 2) == 0);
  nmt(0x01);
  co_node_process_rx(&g_node, 100000); /* not armed before the first RPDO */
  TT_CHECK(g_hooks.rpdo_timeout == 0);
  rx(0x205, 6, d);
  co_node_process_rx(&g_node, 200000);
  TT_CHECK(g_hooks.rpdo == 1);
  co_node_process_rx(&g_node, 219999);
  co_node_process_tx(&g_node, 219999);
  TT_CHECK(g_hooks.rpdo_timeout == 0);
  co_node_process_rx(&g_node, 220000);
  TT_CHECK(g_hooks.rpdo_timeout == 1 && g_hooks.rpdo_timeout_arg == 0u);
  co_node_process_tx(&g_node, 300000);
  TT_CHECK(g_hooks.rpdo_timeout == 1); /* once */
  TT_CHECK(g_node.count.rpdo_timeouts == 1u);
  rx(0x205, 6, d); /* fresh data re-arms */
  co_node_process_rx(&g_node, 310000);
  co_node_process_rx(&g_node, 329000);
  TT_CHECK(g_hooks.rpdo_timeout == 1);
  co_node_process_rx(&g_node, 330000);
  TT_CHECK(g_hooks.rpdo_timeout == 2);
  /* too short: not applied, does not feed the deadline */
  rx(0x205, 6, d);
  co_node_process_rx(&g_node, 400000);
  rx(0x205, 2, d);
  co_node_process_rx(&g_node, 415000);
  co_node_process_rx(&g_node, 420000);
  TT_CHECK(g_hooks.rpdo_timeout == 3);
  /* synchronous RPDO: received every 5 ms but no SYNC -> deadline */
  TT_CHECK(sdo_write(0x1400, 2, 1u, 1) == 0); /* re-configured: disarmed */
  rx(0x205, 6, d);
  rx(0x080, 0, NULL);
  co_node_process_rx(&g_node, 500000);
  int before = g_hooks.rpdo_timeout;
  for (uint32_t t = 505000u; t <= 540000u; t += 5000u) {
    rx(0x205, 6, d);
    co_node_process_rx(&g_node, t);
  }
  TT_CHECK(g_hooks.rpdo_timeout == before + 1);
  /* outside OPERATIONAL nothing is watched; entering it disarms */
  nmt(0x80);
  co_node_process_rx(&g_node, 900000);
  nmt(0x01);
  co_node_process_rx(&g_node, 990000);
  TT_CHECK(g_hooks.rpdo_timeout == before + 1);
  /* 0 = off */
  TT_CHECK(sdo_write(0x1400, 5, 0u, 2) == 0);
  TT_CHECK(sdo_write(0x1400, 2, 255u, 1) == 0);
  rx(0x205, 6, d);
  co_node_process_rx(&g_node, 1000000);
  co_node_process_rx(&g_node, 5000000);
  TT_CHECK(g_hooks.rpdo_timeout == before + 1);
}

static void test_emcy_and_queues(void) {
  fw_can_frame_t f;
  setup();
  uint8_t msef[5] = {1, 2, 3, 4, 5};
  TT_CHECK(co_node_emcy(&g_node, 0x2310, 0x03, msef) == CO_OK);
  TT_CHECK(co_node_tx_pop(&g_node, &f));
  TT_CHECK(f.id == 0x80 + NID && f.dlc == 8);
  TT_CHECK(f.data[0] == 0x10 && f.data[1] == 0x23 && f.data[2] == 0x03 && f.data[7] == 5);
  TT_CHECK(co_node_get_u32(&g_node, CO_OD_1001_00) == 0x03);
  TT_CHECK(sdo_write(0x1014, 0, 0x80000000u | (0x80 + NID), 4) == 0);
  TT_CHECK(co_node_emcy(&g_node, 0x2310, 0x03, NULL) == CO_ERR_STATE);
  TT_CHECK(co_node_emcy(NULL, 0, 0, NULL) == CO_ERR_NULL);
  /* RX overflow counted */
  fw_can_frame_t g;
  memset(&g, 0, sizeof g);
  g.id = 0x123;
  for (unsigned k = 0; k < CO_QUEUE_LEN + 5; k++) co_node_rx_isr(&g_node, &g);
  TT_CHECK(g_node.rxq.dropped == 5);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(co_node_rx_isr(&g_node, &g) == CO_OK);
  TT_CHECK(co_node_rx_isr(NULL, &g) == CO_ERR_NULL);
  /* dlc > 8 clamped */
  g.dlc = 15;
  co_node_rx_isr(&g_node, &g);
  co_node_process_rx(&g_node, 0);
  TT_CHECK(!co_node_tx_pop(NULL, &f));
}

static void test_od_table(void) {
  uint16_t pos;
  TT_CHECK(co_od_find(0x6040, 0, &pos) == CO_OD_OK && pos == CO_OD_6040_00);
  TT_CHECK(co_od_find(0x1018, 7, &pos) == CO_OD_NO_SUB);
  TT_CHECK(co_od_find(0x1002, 0, &pos) == CO_OD_NO_OBJECT);
  TT_CHECK(co_od_find(0x0000, 0, &pos) == CO_OD_NO_OBJECT);
  TT_CHECK(co_od_find(0xFFFF, 0xFF, &pos) == CO_OD_NO_OBJECT);
  for (uint16_t k = 1; k < co_od_count(); k++) {
    const co_od_entry_t *a = co_od_entry((uint16_t)(k - 1)), *b = co_od_entry(k);
    TT_CHECK(((uint32_t)a->index << 8 | a->sub) < ((uint32_t)b->index << 8 | b->sub));
    TT_CHECK(co_od_find(b->index, b->sub, &pos) == CO_OD_OK && pos == k);
  }
  TT_CHECK(co_od_entry(co_od_count()) == NULL);
}

/* ---- compile-time handles and word-wise little-endian access -------------- */

/* Every generated handle CO_OD_OFF_/CO_OD_LEN_<index>_<sub> is the table's offset
 * and size of the entry co_od_find finds, and every entry lies inside the OD RAM. */
static void test_od_handles(void) {
  uint16_t pos;
#define CHECK_HANDLE(id)                                                                  \
  TT_CHECK(co_od_table[CO_OD_##id].offset == CO_OD_OFF_##id &&                           \
           co_od_table[CO_OD_##id].size == CO_OD_LEN_##id);                              \
  TT_CHECK(co_od_find(co_od_table[CO_OD_##id].index, co_od_table[CO_OD_##id].sub, &pos) == \
               CO_OD_OK &&                                                                \
           pos == CO_OD_##id);
  CO_OD_ENTRIES(CHECK_HANDLE)
#undef CHECK_HANDLE
  for (uint16_t k = 0u; k < co_od_count(); k++) {
    const co_od_entry_t *e = co_od_entry(k);
    size_t need = (size_t)e->offset + e->size + (e->type == CO_TYPE_VSTRING ? 1u : 0u);
    TT_CHECK(need <= CO_OD_RAM_SIZE);
  }
}

static uint32_t le_get_ref(const uint8_t *p, size_t n) {
  uint32_t v = 0u;
  for (size_t i = 0u; i < n; i++) {
    v |= (uint32_t)p[i] << (8u * i);
  }
  return v;
}

/* co_le_load / co_le_store (word-wise on a little-endian host) and co_le_get /
 * co_le_put against a byte-wise reference, at every alignment. */
static void test_le_word_access(void) {
  static const uint32_t vals[] = {0u, 1u, 0x80u, 0xFFu, 0x1234u, 0x8001u, 0xFFFFu,
                                  0x123456u, 0x80000000u, 0xDEADBEEFu, 0xFFFFFFFFu};
  for (size_t n = 1u; n <= 4u; n++) {
    for (size_t at = 0u; at < 4u; at++) {
      for (size_t k = 0u; k < sizeof vals / sizeof vals[0]; k++) {
        uint8_t a[12], b[12], ref[12];
        memset(a, 0xA5, sizeof a);
        memset(b, 0xA5, sizeof b);
        memset(ref, 0xA5, sizeof ref);
        for (size_t i = 0u; i < n; i++) {
          ref[at + i] = (uint8_t)(vals[k] >> (8u * i));
        }
        co_le_store(&a[at], n, vals[k]);
        co_le_put(&b[at], n, vals[k]);
        TT_CHECK(memcmp(a, ref, sizeof a) == 0 && memcmp(b, ref, sizeof b) == 0);
        uint32_t want = le_get_ref(&ref[at], n);
        TT_CHECK(co_le_load(&ref[at], n) == want && co_le_get(&ref[at], n) == want);
      }
    }
  }
  uint8_t z[8] = {1, 2, 3, 4, 5, 6, 7, 8};
  co_le_store(z, 5u, 0u); /* n > 4: nothing */
  co_le_put(z, 5u, 0u);
  TT_CHECK(z[0] == 1u && z[4] == 5u);
  TT_CHECK(co_le_get(z, 5u) == 0u && co_le_get(NULL, 2u) == 0u);
}

/* CO_NODE_PUT / _GET / _GET_I / _F32 store and read exactly what co_node_set_* /
 * co_node_get_* do, for every integer size, signed and unsigned, and REAL32. */
static void test_handle_access_matches_setters(void) {
  static co_node_t a, b;
  TT_CHECK(co_node_init(&a, NID, NULL) == CO_OK && co_node_init(&b, NID, NULL) == CO_OK);
  static const int32_t ivals[] = {0, 1, -1, 127, -128, 255, 32767, -32768, 65535, 100000,
                                  -100000, INT32_MAX, INT32_MIN};
  for (size_t k = 0u; k < sizeof ivals / sizeof ivals[0]; k++) {
    int32_t v = ivals[k];
    CO_NODE_PUT(&a, 6041_00, v); /* U16 */
    co_node_set_u32(&b, CO_OD_6041_00, (uint32_t)v);
    CO_NODE_PUT(&a, 6061_00, v); /* I8 */
    co_node_set_i32(&b, CO_OD_6061_00, v);
    CO_NODE_PUT(&a, 6077_00, v); /* I16 */
    co_node_set_i32(&b, CO_OD_6077_00, v);
    CO_NODE_PUT(&a, 6064_00, v); /* I32 */
    co_node_set_i32(&b, CO_OD_6064_00, v);
    CO_NODE_PUT(&a, 2020_08, v); /* U8 */
    co_node_set_u32(&b, CO_OD_2020_08, (uint32_t)v);
    CO_NODE_PUT(&a, 1016_01, v); /* U32 */
    co_node_set_u32(&b, CO_OD_1016_01, (uint32_t)v);
    TT_CHECK(memcmp(a.od, b.od, sizeof a.od) == 0);
    TT_CHECK(CO_NODE_GET(&a, 6041_00) == co_node_get_u32(&b, CO_OD_6041_00));
    TT_CHECK(CO_NODE_GET(&a, 1016_01) == co_node_get_u32(&b, CO_OD_1016_01));
    TT_CHECK(CO_NODE_GET_I(&a, 6061_00) == co_node_get_i32(&b, CO_OD_6061_00));
    TT_CHECK(CO_NODE_GET_I(&a, 6077_00) == co_node_get_i32(&b, CO_OD_6077_00));
    TT_CHECK(CO_NODE_GET_I(&a, 6064_00) == co_node_get_i32(&b, CO_OD_6064_00));
  }
  static const float fvals[] = {0.0f, -0.0f, 1.5f, -3.25e-7f, 1.0e30f};
  for (size_t k = 0u; k < sizeof fvals / sizeof fvals[0]; k++) {
    CO_NODE_PUT_F32(&a, 2020_01, fvals[k]);
    co_node_set_f32(&b, CO_OD_2020_01, fvals[k]);
    TT_CHECK(memcmp(a.od, b.od, sizeof a.od) == 0);
    TT_CHECK(CO_NODE_GET_F32(&a, 2020_01) == co_node_get_f32(&b, CO_OD_2020_01));
  }
}

int main(void) {
  TT_RUN(test_od_table);
  TT_RUN(test_boot_and_nmt);
  TT_RUN(test_sdo_expedited);
  TT_RUN(test_sdo_aborts);
  TT_RUN(test_sdo_segmented_upload);
  TT_RUN(test_sdo_segmented_download);
  TT_RUN(test_pdo_remap_and_rpdo);
  TT_RUN(test_tpdo);
  TT_RUN(test_heartbeat);
  TT_RUN(test_comm_write_rules);
  TT_RUN(test_heartbeat_timeout_seen_in_rx);
  TT_RUN(test_rpdo_deadline);
  TT_RUN(test_emcy_and_queues);
  TT_RUN(test_od_handles);
  TT_RUN(test_le_word_access);
  TT_RUN(test_handle_access_matches_setters);
  return TT_SUMMARY();
}
