#!/usr/bin/env bash
# Build the libFuzzer harnesses under ASan + UBSan and run each for N seconds.
#
#   tests/fuzz/run.sh [seconds-per-target] [target...]
#
# Targets: fuzz_sdo fuzz_pdo fuzz_serial fuzz_app fuzz_slcan (default: all; fuzz_app
# includes the control core and the application glue, fuzz_slcan the boards' serial-line
# CAN endpoint firmware_c/boards/_common/slcan.c). Corpora persist in
# build/comm/fuzz/corpus/<target> (seeded from tests/fuzz/seeds/<target> if
# present); crashes are written to build/comm/fuzz/artifacts/. Prints one
# summary line per target: "FUZZ <target> runs=<n> exec/s=<n> cov=<n> ft=<n>".
# A long run: tests/fuzz/run.sh 3600 (or -jobs via FUZZ_ARGS="-jobs=8 -workers=8").
set -euo pipefail
SECS="${1:-10}"
shift || true
TARGETS=("$@")
[ ${#TARGETS[@]} -eq 0 ] && TARGETS=(fuzz_sdo fuzz_pdo fuzz_serial fuzz_app fuzz_slcan)
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
OUT="$ROOT/build/comm/fuzz"
CC="${FUZZ_CC:-clang}"
mkdir -p "$OUT/artifacts"
COMM="$ROOT/firmware_c/comm"
SRCS=("$COMM"/src/co_*.c "$COMM/src/fw_serial.c"
      "$COMM/generated/co_od_table.c" "$COMM/generated/fw_serial_signals.c")
FLAGS=(-std=c11 -g -O1 -fno-omit-frame-pointer
       -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all
       -I"$COMM/include" -I"$COMM/generated" -I"$ROOT/firmware_c/include")
rc=0
for t in "${TARGETS[@]}"; do
  extra=()
  if [ "$t" = fuzz_app ]; then
    extra=("$COMM"/src/fw_app*.c "$COMM/src/fw_nvm.c" "$COMM/src/fw_trace.c"
           "$COMM/generated/fw_app_hooks.c" "$ROOT"/firmware_c/src/*.c)
  elif [ "$t" = fuzz_slcan ]; then
    extra=(-I"$ROOT/firmware_c/boards/_common" "$ROOT/firmware_c/boards/_common/slcan.c")
  fi
  "$CC" "${FLAGS[@]}" -o "$OUT/$t" "$ROOT/tests/fuzz/$t.c" "${SRCS[@]}" "${extra[@]}" -lm
  mkdir -p "$OUT/corpus/$t"
  seeds=()
  [ -d "$ROOT/tests/fuzz/seeds/$t" ] && seeds=("$ROOT/tests/fuzz/seeds/$t")
  log="$OUT/$t.log"
  set +e
  UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 ASAN_OPTIONS=detect_leaks=1 \
    "$OUT/$t" -max_total_time="$SECS" -print_final_stats=1 \
    -artifact_prefix="$OUT/artifacts/$t-" ${FUZZ_ARGS:-} \
    "$OUT/corpus/$t" "${seeds[@]}" >"$log" 2>&1
  r=$?
  set -e
  line=$(grep -E '^#[0-9]+.*(DONE|pulse|NEW|REDUCE)' "$log" | tail -1 || true)
  runs=$(grep -E 'stat::number_of_executed_units' "$log" | awk '{print $2}')
  eps=$(grep -E 'stat::average_exec_per_sec' "$log" | awk '{print $2}')
  cov=$(echo "$line" | sed -n 's/.*cov: \([0-9]*\).*/\1/p')
  ft=$(echo "$line" | sed -n 's/.*ft: \([0-9]*\).*/\1/p')
  echo "FUZZ $t runs=${runs:-?} exec/s=${eps:-?} cov=${cov:-?} ft=${ft:-?} rc=$r"
  if [ $r -ne 0 ]; then
    rc=1
    grep -E 'ERROR|runtime error|SUMMARY' "$log" | head -20 || true
  fi
done
exit $rc
