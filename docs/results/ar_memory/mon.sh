#!/bin/bash
# usage: mon.sh TAG cmd...   -> /tmp/hmem/TAG.time (time -v), TAG.rss (t, VmRSS kB), TAG.log (stdout with t)
TAG=$1; shift
cd /work/main
export JAX_PLATFORMS=cpu WANDB_MODE=disabled
T0=$(date +%s.%N)
( nice -n 10 /usr/bin/time -v -o /tmp/hmem/$TAG.time "$@" 2>&1 | while IFS= read -r l; do echo "$(echo "$(date +%s.%N) - $T0" | bc) $l"; done > /tmp/hmem/$TAG.log ) &
sleep 1
PID=$(pgrep -n -f "handx train ar.*$TAG")
: > /tmp/hmem/$TAG.rss
while kill -0 $PID 2>/dev/null; do echo "$(echo "$(date +%s.%N) - $T0" | bc) $(grep VmRSS /proc/$PID/status | awk '{print $2}')" >> /tmp/hmem/$TAG.rss; sleep 0.5; done
wait
