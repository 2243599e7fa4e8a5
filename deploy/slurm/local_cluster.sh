#!/usr/bin/env bash
# A one-node SLURM cluster on this machine (Debian/Ubuntu, as root), to try deploy/slurm/ for real:
# the node is this host (`hostname -s`), with its CPUs (nproc) and memory (free); one partition `local`.
#
#   deploy/slurm/local_cluster.sh          # = start: install, configure, start, wait until the node is idle
#   deploy/slurm/local_cluster.sh status   # sinfo and the daemons' pids
#   deploy/slurm/local_cluster.sh stop     # stop slurmd, slurmctld and munged (config and packages stay)
#
# Safe to re-run: packages are installed once, the config is rewritten only when it changes (then the
# daemons restart), running daemons are kept. With systemd the Debian units start the daemons;
# without it (containers, VMs started without an init) they are started here directly.
# No cgroups needed: proctrack/linuxproc tracks job processes, task/none binds nothing.
# Variables: NODE_CPUS, NODE_MEM_MB (override what nproc/free say), PARTITION (default: local),
# JOB_NICE (default 19: job tasks of this test cluster yield the CPU to everything else on the host; 0 = none).
set -euo pipefail

CONF_DIR=/etc/slurm
LOG_DIR=/var/log/slurm
STATE_DIR=/var/lib/slurm
RUN_DIR=/run/slurm
NODE=$(hostname -s)
PARTITION=${PARTITION:-local}
JOB_NICE=${JOB_NICE:-19}

log() { echo "local_cluster: $*" >&2; }
die() { log "$*"; exit 1; }
have_systemd() { [ -d /run/systemd/system ]; }
pid_alive() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

install_packages() {
    if command -v slurmctld >/dev/null && command -v slurmd >/dev/null && command -v munged >/dev/null \
        && command -v sbatch >/dev/null; then
        return
    fi
    log "installing slurm-wlm and munge (apt-get)"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q
    apt-get install -y -q --no-install-recommends slurm-wlm munge
}

write_if_changed() {  # write stdin to $1; exit status 0 when the file changed
    local tmp
    tmp=$(mktemp)
    cat >"$tmp"
    if [ -f "$1" ] && cmp -s "$tmp" "$1"; then
        rm -f "$tmp"
        return 1
    fi
    install -m 644 "$tmp" "$1"
    rm -f "$tmp"
}

write_config() {  # exit status 0 when a file changed
    local cpus mem changed=1
    cpus=${NODE_CPUS:-$(nproc)}
    # leave 5% to the OS: slurmd drains a node whose RealMemory is above what it measures
    mem=${NODE_MEM_MB:-$(free -m | awk '/^Mem:/ {print int($2 * 0.95)}')}
    mkdir -p "$CONF_DIR" "$LOG_DIR" "$STATE_DIR/slurmctld" "$STATE_DIR/slurmd" "$RUN_DIR"
    chown slurm:slurm "$LOG_DIR" "$STATE_DIR/slurmctld"
    write_if_changed "$CONF_DIR/slurm.conf" <<EOF && changed=0
# written by deploy/slurm/local_cluster.sh: one node, this host
ClusterName=gvf-local
SlurmctldHost=$NODE
SlurmUser=slurm
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
MpiDefault=none
# no cgroups: works in containers and VMs without systemd
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
# CPUs are the consumable: two 1-CPU tasks share a 2-CPU node
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
# a restarted slurmd brings its node back instead of leaving it down
ReturnToService=2
StateSaveLocation=$STATE_DIR/slurmctld
SlurmdSpoolDir=$STATE_DIR/slurmd
SlurmctldPidFile=$RUN_DIR/slurmctld.pid
SlurmdPidFile=$RUN_DIR/slurmd.pid
SlurmctldLogFile=$LOG_DIR/slurmctld.log
SlurmdLogFile=$LOG_DIR/slurmd.log
TaskProlog=$CONF_DIR/task_prolog.sh
# a cancelled job's processes get 30 s between SIGTERM and SIGKILL (the default, said here): time to close cleanly
KillWait=30
# refuse at submission a job no node can run (more CPUs per task than the node has) instead of pending for ever
EnforcePartLimits=ALL
# no mail server here
MailProg=/bin/true
# scheduling every second instead of the default 60 s backfill sweep: jobs start within seconds
SchedulerParameters=bf_interval=1,sched_min_interval=100000
NodeName=$NODE NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=$PARTITION Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
    write_if_changed "$CONF_DIR/cgroup.conf" <<EOF && changed=0
# written by deploy/slurm/local_cluster.sh: no cgroup plugin is used (proctrack/linuxproc, task/none)
CgroupPlugin=autodetect
ConstrainCores=no
ConstrainRAMSpace=no
EOF
    # runs as the job's user in each task's session before it starts: the session's CPU priority
    write_if_changed "$CONF_DIR/task_prolog.sh" <<EOF && changed=0
#!/bin/sh
[ "$JOB_NICE" = 0 ] || echo "$JOB_NICE" > /proc/self/autogroup 2>/dev/null || renice -n "$JOB_NICE" -p \$PPID >/dev/null 2>&1
exit 0
EOF
    chmod 755 "$CONF_DIR/task_prolog.sh"
    return $changed
}

start_munge() {
    if pgrep -x munged >/dev/null; then return; fi
    if have_systemd; then systemctl start munge; return; fi
    [ -s /etc/munge/munge.key ] || runuser -u munge -- /usr/sbin/mungekey --create
    install -d -o munge -g munge -m 755 /run/munge
    runuser -u munge -- /usr/sbin/munged
}

start_slurm() {
    if have_systemd; then
        systemctl start slurmctld slurmd
        return
    fi
    pid_alive "$RUN_DIR/slurmctld.pid" || /usr/sbin/slurmctld
    pid_alive "$RUN_DIR/slurmd.pid" || /usr/sbin/slurmd
}

stop_slurm() {
    if have_systemd; then
        systemctl stop slurmd slurmctld || true
        return
    fi
    local d pid
    for d in slurmd slurmctld; do
        pid_alive "$RUN_DIR/$d.pid" || continue
        pid=$(cat "$RUN_DIR/$d.pid")
        kill "$pid"
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
    done
}

stop_munge() {
    if have_systemd; then systemctl stop munge || true; return; fi
    [ -s /run/munge/munged.pid ] && kill "$(cat /run/munge/munged.pid)" 2>/dev/null || true
}

wait_idle() {  # until sinfo shows the node idle (or mixed/allocated: it is up and taking jobs)
    local state
    for _ in $(seq 60); do
        state=$(sinfo -h -n "$NODE" -o %T 2>/dev/null | head -1 || true)
        case "$state" in
            idle | mixed | allocated | completing) log "node $NODE is $state"; sinfo; return 0 ;;
            down* | drain* | drained*) scontrol update NodeName="$NODE" State=RESUME 2>/dev/null || true ;;
        esac
        sleep 1
    done
    die "node $NODE not idle after 60 s (state: ${state:-none}); see $LOG_DIR/slurmctld.log and $LOG_DIR/slurmd.log"
}

cmd_start() {
    [ "$(id -u)" -eq 0 ] || die "run as root (installs packages, writes $CONF_DIR, starts daemons)"
    install_packages
    start_munge
    if write_config; then
        log "configuration changed: restarting slurmctld and slurmd"
        stop_slurm
    fi
    start_slurm
    wait_idle
}

case "${1:-start}" in
    start) cmd_start ;;
    stop) stop_slurm; stop_munge; log "stopped" ;;
    status)
        sinfo || true
        for d in slurmctld slurmd; do pid_alive "$RUN_DIR/$d.pid" && echo "$d: pid $(cat "$RUN_DIR/$d.pid")" || echo "$d: not running"; done
        pgrep -x munged >/dev/null && echo "munged: pid $(pgrep -x munged)" || echo "munged: not running"
        ;;
    *) die "usage: $0 [start|stop|status]" ;;
esac
