/**
 * @file sim_nvm.c
 * @brief The simulated drive's non-volatile memory (fw_port.h nvm functions):
 *        one file per simulated drive, replaced atomically (write to
 *        "<path>.tmp", fsync, rename), so a crash while saving leaves the
 *        old block or the new one, never a mix.
 *
 * Python (bench/_simserver.py) allocates a port of sim_nvm_port_sizeof()
 * bytes, sets its file with sim_nvm_port_init() and hands fw_port_nvm_read /
 * fw_port_nvm_write to the drive application (fw_app_attach_nvm).
 */
#define _POSIX_C_SOURCE 200809L

#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "pmlsm/fw_port.h"

#define SIM_NVM_PATH_MAX 4096u

struct fw_port {
  char path[SIM_NVM_PATH_MAX];
  char tmp[SIM_NVM_PATH_MAX + 8u];
};

size_t sim_nvm_port_sizeof(void);
int sim_nvm_port_init(fw_port_t *port, const char *path);

size_t sim_nvm_port_sizeof(void) { return sizeof(struct fw_port); }

/** Set the file; 0 on success, -1 when the path is empty or too long. */
int sim_nvm_port_init(fw_port_t *port, const char *path) {
  if (port == NULL || path == NULL) {
    return -1;
  }
  size_t n = strlen(path);
  if (n == 0u || n >= SIM_NVM_PATH_MAX) {
    return -1;
  }
  memcpy(port->path, path, n + 1u);
  memcpy(port->tmp, path, n);
  memcpy(&port->tmp[n], ".tmp", 5u);
  return 0;
}

fw_nvm_status_t fw_port_nvm_read(fw_port_t *port, uint8_t *buf, size_t cap, size_t *len) {
  if (port == NULL || buf == NULL || len == NULL) {
    return FW_NVM_ERROR;
  }
  *len = 0u;
  FILE *f = fopen(port->path, "rb");
  if (f == NULL) {
    return FW_NVM_EMPTY;
  }
  size_t n = fread(buf, 1u, cap, f);
  int more = fgetc(f); /* a file larger than the block cannot be ours */
  int err = ferror(f);
  (void)fclose(f);
  if (err != 0 || more != EOF) {
    return FW_NVM_ERROR;
  }
  *len = n;
  return n == 0u ? FW_NVM_EMPTY : FW_NVM_OK;
}

fw_nvm_status_t fw_port_nvm_write(fw_port_t *port, const uint8_t *data, size_t len) {
  if (port == NULL || (data == NULL && len > 0u)) {
    return FW_NVM_ERROR;
  }
  if (len == 0u) { /* erase */
    return (remove(port->path) == 0 || access(port->path, F_OK) != 0) ? FW_NVM_OK
                                                                       : FW_NVM_ERROR;
  }
  FILE *f = fopen(port->tmp, "wb");
  if (f == NULL) {
    return FW_NVM_ERROR;
  }
  size_t n = fwrite(data, 1u, len, f);
  int ok = n == len && fflush(f) == 0 && fsync(fileno(f)) == 0;
  ok = (fclose(f) == 0) && ok;
  if (!ok || rename(port->tmp, port->path) != 0) {
    (void)remove(port->tmp);
    return FW_NVM_ERROR;
  }
  return FW_NVM_OK;
}
