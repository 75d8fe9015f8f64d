#!/usr/bin/env bash
# One line at the end of `make test`: every test that skipped and why (from the log that
# crates/testkit appends to when DEPTHSENSE_SKIP_LOG is set). Zero is expected in CI, except
# the browser test (`make test-browser` runs it).
log=${1:?usage: scripts/skip-summary.sh SKIP_LOG}
if [[ ! -s $log ]]; then
  echo "skip summary: 0 tests skipped"
  exit 0
fi
n=$(sort -u "$log" | wc -l)
list=$(sort -u "$log" | awk -F'\t' '{printf "%s%s (%s)", (NR>1 ? "; " : ""), $1, $2}')
echo "skip summary: $n test(s) skipped: $list"
