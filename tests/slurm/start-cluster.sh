#!/bin/bash
# Starts a one-node Slurm cluster on this machine (controller, node daemon and munge), for
# tests/slurm_cluster.rs. Needs root and Debian's packages slurmctld, slurmd, slurm-client and
# munge, which it installs with apt-get when they are missing. Idempotent: a cluster it started
# before is reused. It refuses to touch a slurm.conf it did not write.
#
#   sudo tests/slurm/start-cluster.sh       # then: sinfo
set -euo pipefail

MARK="# written by chaoscope tests/slurm/start-cluster.sh"
CONF=/etc/slurm/slurm.conf

if [[ $(id -u) -ne 0 ]]; then
    echo "start-cluster.sh: needs root (it installs packages and starts daemons)" >&2
    exit 1
fi

if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null \
    || ! command -v sbatch >/dev/null || ! command -v munged >/dev/null; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q >/dev/null
    apt-get install -y -q slurmctld slurmd slurm-client munge >/dev/null
fi

if [[ -e $CONF ]] && ! grep -qF "$MARK" "$CONF"; then
    echo "start-cluster.sh: $CONF exists and was not written by this script; not touching it" >&2
    exit 1
fi

# Munge authenticates every Slurm message; its key comes with the package.
if [[ ! -s /etc/munge/munge.key ]]; then
    mungekey --create --keyfile=/etc/munge/munge.key
    chown munge:munge /etc/munge/munge.key
    chmod 600 /etc/munge/munge.key
fi
install -d -o munge -g munge -m 755 /run/munge
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
    runuser -u munge -- /usr/sbin/munged
    for _ in $(seq 50); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.1; done
fi

node=$(hostname -s)
# The node's real CPUs and memory, as slurmd sees them (a node that claims more is drained).
cpus=$(slurmd -C | sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' | head -1)
mem=$(slurmd -C | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' | head -1)
mem=$((mem * 9 / 10))
install -d /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
cat >"$CONF" <<CONF
$MARK
ClusterName=chaoscope-test
SlurmctldHost=$node
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
# No cgroups in containers: track processes by their parent.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
JobRequeue=1
# Keep finished jobs visible to scontrol for a while (the test reads their state).
MinJobAge=600
NodeName=$node CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$node Default=YES MaxTime=INFINITE State=UP
CONF

if ! scontrol ping 2>/dev/null | grep -q UP; then
    slurmctld
fi
if ! pgrep -x slurmd >/dev/null; then
    slurmd
fi
for _ in $(seq 100); do
    state=$(sinfo -h -n "$node" -o %t 2>/dev/null || true)
    [[ $state == idle* || $state == mix* || $state == alloc* ]] && break
    sleep 0.2
done
state=$(sinfo -h -n "$node" -o %t 2>/dev/null || true)
if [[ $state != idle* && $state != mix* && $state != alloc* ]]; then
    echo "start-cluster.sh: node $node is '$state', not idle; see /var/log/slurm/*.log" >&2
    scontrol update nodename="$node" state=resume 2>/dev/null || true
    exit 1
fi
echo "slurm: one-node cluster up on $node ($cpus CPUs)"
