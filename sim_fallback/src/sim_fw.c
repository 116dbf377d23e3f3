/*
 * Adapters that plug the firmware core (fw_ctrl_t from firmware_c/, linked
 * as the pmlsm_fw target: same sources, never a copy) into the simulator's
 * controller port.
 */
#include <stdlib.h>
#include <string.h>

#include "sim_internal.h"

void sim_fw_step(void *ctx, const fw_inputs_t *in, fw_outputs_t *out) {
  fw_step((fw_ctrl_t *)ctx, in, out);
}

void sim_fw_step_adc(void *ctx, const fw_adc_inputs_t *in, fw_outputs_t *out) {
  fw_step_adc((fw_ctrl_t *)ctx, in, out);
}

void sim_fw_snapshot(const void *ctx, fw_snapshot_t *snap) {
  fw_get_snapshot((const fw_ctrl_t *)ctx, snap);
}

void sim_fw_set_ref(void *ctx, sim_ref_kind_t kind, double value) {
  fw_ctrl_t *c = (fw_ctrl_t *)ctx;
  if (kind == SIM_REF_SPEED) {
    (void)fw_set_speed_ref(c, (float)value);
  } else if (kind == SIM_REF_FORCE) {
    (void)fw_set_force_ref(c, (float)value); /* i_q from the controller's K_F */
  }
}

void sim_fw_port(fw_ctrl_t *ctrl, sim_controller_t *port) {
  memset(port, 0, sizeof *port);
  port->ctx = ctrl;
  /* raw counts only: the firmware's own ADC conversion and range check
   * (fw_step_adc), the one the MCU runs; the plant never converts for it */
  port->step_adc = sim_fw_step_adc;
  port->snapshot = sim_fw_snapshot;
  port->set_ref = sim_fw_set_ref;
}

fw_ctrl_t *sim_fw_new(void) { return (fw_ctrl_t *)calloc(1, sizeof(fw_ctrl_t)); }
void sim_fw_free(fw_ctrl_t *ctrl) { free(ctrl); }
