#!/usr/bin/env bash
# Line/branch coverage reached by the fuzz corpora (run tests/fuzz/run.sh first).
#   tests/fuzz/coverage.sh
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
OUT="$ROOT/build/comm/fuzz/cov"
COMM="$ROOT/firmware_c/comm"
mkdir -p "$OUT"
SRCS=("$COMM"/src/co_*.c "$COMM/src/fw_serial.c"
      "$COMM/generated/co_od_table.c" "$COMM/generated/fw_serial_signals.c")
objs=()
for t in fuzz_sdo fuzz_pdo fuzz_serial; do
  clang -std=c11 -g -O0 -fsanitize=fuzzer -fprofile-instr-generate -fcoverage-mapping \
    -I"$COMM/include" -I"$COMM/generated" -I"$ROOT/firmware_c/include" \
    -o "$OUT/$t" "$ROOT/tests/fuzz/$t.c" "${SRCS[@]}" -lm
  LLVM_PROFILE_FILE="$OUT/$t.profraw" "$OUT/$t" -runs=0 "$ROOT/build/comm/fuzz/corpus/$t" \
    >/dev/null 2>&1
  objs+=("-object=$OUT/$t")
done
llvm-profdata merge -o "$OUT/all.profdata" "$OUT"/*.profraw
llvm-cov report "${objs[@]:1}" "$OUT/fuzz_sdo" -instr-profile="$OUT/all.profdata" \
  "$COMM"/src/co_*.c "$COMM/src/fw_serial.c"
