#!/bin/bash
# Wall time of the default run (`python main.py`: plane, rk4, 151 frames at 1280x720, video) with
# --pipeline serial and overlap, interleaved; one warm-up of each first (kernel cache).
# Usage: scripts/pipeline_walltime.sh [REPEATS] [OUT.tsv]   (run from the repository root)
set -u
repeats=${1:-3}; out=${2:-/dev/stdout}
py=${PYTHON:-.venv/bin/python}
run() {  # mode label
  local t0 t1 load
  load=$(cut -d' ' -f1-3 /proc/loadavg)
  t0=$(date +%s.%N)
  /usr/bin/time -f "%U %S" -o /tmp/pipeline_walltime.cpu $py main.py run --scene plane --integrator rk4 \
      --video out/plane-rk4-$1.mp4 --pipeline $1 >/dev/null 2>/tmp/pipeline_walltime.err || { cat /tmp/pipeline_walltime.err; exit 1; }
  t1=$(date +%s.%N)
  printf "%s\t%s\t%.2f\t%s\t%s\n" "$2" "$1" "$(echo "$t1 - $t0" | bc)" "$(awk '{print $1+$2}' /tmp/pipeline_walltime.cpu)" "$load" >> "$out"
}
printf "round\tpipeline\twall_s\tcpu_s\tloadavg_before\n" >> "$out"
run serial warmup; run overlap warmup
for r in $(seq 1 "$repeats"); do
  if (( r % 2 )); then run serial $r; run overlap $r; else run overlap $r; run serial $r; fi
done
