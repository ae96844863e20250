#!/usr/bin/env bash
# Start a single-node SLURM on this machine (partition `debug`), so that the tests of
# `rbstudy sweep --cluster` run their jobs on a real batch system (tests/test_slurm.py).
#
# Run as root where apt-get is available (Debian, Ubuntu). Installs slurm-wlm and munge if
# they are missing, writes a cgroup-free slurm.conf naming this host with its cores and
# memory, creates a munge key, starts munged, slurmctld and slurmd directly (no systemd),
# and waits until the node is idle. Idempotent: with the node already idle it does
# nothing. Exits non-zero with one line saying why when it cannot; the SLURM tests then
# skip, naming the reason.
set -uo pipefail

CONF=/etc/slurm/slurm.conf
# The first line of a slurm.conf this script wrote: another one is never overwritten.
MARK="# written by rbstudy .ci/start_slurm.sh"
# Seconds to wait for the node to report idle after the daemons start: slurmd registers
# within a few seconds on an idle machine.
IDLE_WAIT=60

fail() { echo "start_slurm: $*" >&2; exit 1; }

node_idle() {  # partition debug is up and its node takes jobs (idle, or some running)
  sinfo --noheader --partition debug --format '%a %T' 2>/dev/null | grep -qE '^up (idle|mixed|allocated)'
}

started=$(date +%s)
# sinfo waits out its MessageTimeout (10 s) when no controller runs: asked only when one does
if command -v sinfo >/dev/null && pgrep -x slurmctld >/dev/null && node_idle; then
  echo "start_slurm: SLURM is already running (partition debug up, node idle)"
  exit 0
fi
[ "$(id -u)" -eq 0 ] || fail "needs root to install and start SLURM"

if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null || ! command -v munged >/dev/null; then
  command -v apt-get >/dev/null || fail "slurm-wlm and munge are not installed and there is no apt-get"
  export DEBIAN_FRONTEND=noninteractive
  { apt-get update -qq && apt-get install -y -qq slurm-wlm munge; } >/tmp/start_slurm.apt.log 2>&1 \
    || fail "apt-get install slurm-wlm munge failed (see /tmp/start_slurm.apt.log)"
fi

host=$(hostname -s)
if [ -e "$CONF" ] && [ "$(head -n 1 "$CONF")" != "$MARK" ]; then
  fail "$CONF exists and was not written by this script; start that SLURM instead"
fi
# slurmd -C prints this machine's node line: its CPUs, sockets, cores, threads, memory.
node=$(slurmd -C 2>/dev/null | head -n 1)
[[ "$node" == NodeName=* ]] || fail "slurmd -C did not describe this machine"
node="${node/NodeName=* CPUs=/NodeName=$host CPUs=}"
mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
cat >"$CONF" <<EOF
$MARK
# the name tests/test_slurm.py looks for before it takes partition debug down
ClusterName=rbstudy
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
# no cgroups: processes are tracked by their parents, tasks are not bound
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
MpiDefault=none
ReturnToService=2
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
$node State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF

if [ ! -s /etc/munge/munge.key ]; then
  mkdir -p /etc/munge
  if command -v mungekey >/dev/null; then
    mungekey --create --keyfile /etc/munge/munge.key >/dev/null 2>&1 || fail "mungekey could not create the munge key"
  else
    dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null
  fi
fi
chown -R munge:munge /etc/munge /var/lib/munge /var/log/munge 2>/dev/null
chmod 0400 /etc/munge/munge.key
mkdir -p /run/munge && chown munge:munge /run/munge
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  runuser -u munge -- munged || fail "munged did not start (see /var/log/munge/munged.log)"
fi
if ! scontrol ping 2>/dev/null | grep -q UP; then
  slurmctld || fail "slurmctld did not start (see /var/log/slurm/slurmctld.log)"
fi
if ! pgrep -x slurmd >/dev/null; then
  slurmd || fail "slurmd did not start (see /var/log/slurm/slurmd.log)"
fi
# a partition left down (by an interrupted test of a job that never starts) is brought up
scontrol update PartitionName=debug State=UP 2>/dev/null
for _ in $(seq "$IDLE_WAIT"); do
  if node_idle; then
    echo "start_slurm: SLURM is running on $host (partition debug) after $(( $(date +%s) - started )) s"
    exit 0
  fi
  sleep 1
done
fail "the node $host did not become idle within $IDLE_WAIT s: $(sinfo --noheader --format '%a %T %E' 2>&1 | head -n 1)"
