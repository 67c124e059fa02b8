# Sourced by the scripts that run long jobs: `lower_priority` gives this script's session the lowest
# CPU share (NICE, default 19) when the script leads its own session (started with setsid, as the
# background launches are), and leaves the caller's session alone otherwise.
#
# Why `nice` alone is not enough: with Linux autogroup scheduling (kernel.sched_autogroup_enabled = 1,
# the default on desktop and many server kernels) the scheduler first shares the CPUs fairly between
# sessions and only then between the processes of a session by their nice values. A background run
# in its own session (setsid) at nice 19 therefore still takes half of a 2-core machine from an
# interactive test run. The session's own nice value, /proc/self/autogroup, lowers the whole group.
lower_priority() {
  local n=${NICE:-19} sid
  sid=$(ps -o sid= -p $$ 2>/dev/null | tr -d ' ')
  if [ "$sid" = "$$" ] && [ -w /proc/self/autogroup ]; then
    echo "$n" > /proc/self/autogroup 2>/dev/null || true
  fi
}
