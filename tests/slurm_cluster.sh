#!/usr/bin/env bash
# A one-node SLURM cluster with accounting (slurmdbd + a private MariaDB) on localhost, for tests.
#
#   tests/slurm_cluster.sh start DIR   install if needed (apt-get, as root), start everything under DIR,
#                                      print SLURM_CONF=DIR/etc/slurm.conf; exit 1 with the reason if not up
#   tests/slurm_cluster.sh stop DIR    stop the daemons started by `start DIR` (by their pid files)
#
# Recipe measured on these machines in ../shared/reference/slurm-ci.md (Debian bookworm, root, no
# systemd): munged → mariadbd → slurmdbd → slurmctld → slurmd; up in 3–6 s after a ~30 s install.
# Every wait has a time limit. Ports are chosen away from the defaults so a system SLURM or MariaDB
# is left alone.
set -euo pipefail

cmd=${1:-}
DIR=${2:-}
[ -n "$cmd" ] && [ -n "$DIR" ] || { echo "usage: $0 start|stop DIR" >&2; exit 2; }
DIR=$(mkdir -p "$DIR" && cd "$DIR" && pwd)
HOST=$(hostname -s)
DB_PORT=${HANDX_SLURM_DB_PORT:-13306}
DBD_PORT=${HANDX_SLURM_DBD_PORT:-16819}
CTLD_PORT=${HANDX_SLURM_CTLD_PORT:-16817}
SLURMD_PORT=${HANDX_SLURM_SLURMD_PORT:-16818}

die() { echo "slurm_cluster: $*" >&2; for f in "$DIR"/log/*.log "$DIR"/mysql/err; do [ -f "$f" ] && { echo "--- $f" >&2; tail -n 15 "$f" >&2; }; done; exit 1; }

wait_for() {  # wait_for SECONDS DESCRIPTION COMMAND...
  local limit=$1 what=$2; shift 2
  local end=$((SECONDS + limit))
  until "$@" >/dev/null 2>&1; do
    [ $SECONDS -lt $end ] || die "$what did not come up within ${limit}s"
    sleep 0.2
  done
}

stop_pidfile() {  # stop_pidfile FILE: TERM, wait up to 15 s, then KILL
  local f=$1 pid
  [ -f "$f" ] || return 0
  pid=$(cat "$f" 2>/dev/null || true)
  if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
    kill "$pid" 2>/dev/null || true
    for _ in $(seq 75); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
    kill -9 "$pid" 2>/dev/null || true
  fi
  rm -f "$f"
}

if [ "$cmd" = stop ]; then
  export SLURM_CONF="$DIR/etc/slurm.conf"
  stop_pidfile "$DIR/run/slurmd.pid"
  stop_pidfile "$DIR/run/slurmctld.pid"
  stop_pidfile "$DIR/run/slurmdbd.pid"
  stop_pidfile "$DIR/mysql/pid"
  stop_pidfile "$DIR/run/munged.pid"  # only if we started it
  exit 0
fi
[ "$cmd" = start ] || { echo "usage: $0 start|stop DIR" >&2; exit 2; }

[ "$(id -u)" = 0 ] || die "needs root (to install packages and run slurmd/munged); running as $(id -un)"
need=()
have() { for b in "$@"; do command -v "$b" >/dev/null || return 1; done; }
have slurmctld slurmd sbatch squeue scancel sacct sacctmgr sinfo srun || need+=(slurm-wlm)
have munged munge unmunge || need+=(munge)
have slurmdbd || need+=(slurmdbd)
have mariadbd mariadb-install-db mariadb || need+=(mariadb-server)
if [ ${#need[@]} -gt 0 ]; then
  command -v apt-get >/dev/null || die "APT-UNAVAILABLE: ${need[*]} missing and there is no apt-get"
  export DEBIAN_FRONTEND=noninteractive
  # Keep the packages' init scripts from starting system-wide daemons (we start our own below).
  policy=""
  if [ ! -e /usr/sbin/policy-rc.d ]; then
    policy=/usr/sbin/policy-rc.d
    printf '#!/bin/sh\nexit 101\n' >"$policy" && chmod +x "$policy"
  fi
  ok=0
  apt-get install -y -q "${need[@]}" >"$DIR/apt.log" 2>&1 \
    || { apt-get update -q >>"$DIR/apt.log" 2>&1 && apt-get install -y -q "${need[@]}" >>"$DIR/apt.log" 2>&1; } \
    || ok=1
  [ -n "$policy" ] && rm -f "$policy"
  [ $ok = 0 ] || { tail -n 20 "$DIR/apt.log" >&2; die "apt-get install ${need[*]} failed"; }
fi

mkdir -p "$DIR"/{etc,log,run,state,spool,mysql}
chown -R slurm:slurm "$DIR/log" "$DIR/state" "$DIR/run"
chmod 755 "$DIR" "$DIR/etc" "$DIR/log" "$DIR/run"

# munge: reuse a running munged, else start one (its key is created by the package, or here).
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  mkdir -p /run/munge /var/log/munge /var/lib/munge && chown munge:munge /run/munge /var/log/munge /var/lib/munge
  chmod 755 /run/munge
  if [ ! -s /etc/munge/munge.key ]; then
    mungekey --create --keyfile=/etc/munge/munge.key 2>/dev/null || dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 2>/dev/null
  fi
  chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
  runuser -u munge -- /usr/sbin/munged --pid-file="$DIR/run/munged.pid.tmp" >"$DIR/log/munged.log" 2>&1 \
    || runuser -u munge -- /usr/sbin/munged >"$DIR/log/munged.log" 2>&1 || die "munged did not start"
  wait_for 10 munge bash -c 'munge -n | unmunge'
  rm -f "$DIR/run/munged.pid.tmp"
  # The one just started (newest munged of the munge user), stopped by `stop`.
  if command -v pgrep >/dev/null; then
    pgrep -n -u munge -x munged >"$DIR/run/munged.pid" || true
  else
    for p in /proc/[0-9]*; do [ "$(cat "$p/comm" 2>/dev/null)" = munged ] && echo "${p#/proc/}"; done | sort -n | tail -n 1 >"$DIR/run/munged.pid"
  fi
fi

# MariaDB, a private instance on 127.0.0.1:$DB_PORT with its data under DIR/mysql.
chown -R mysql:mysql "$DIR/mysql"
if [ ! -d "$DIR/mysql/data/mysql" ]; then
  mariadb-install-db --no-defaults --user=mysql --datadir="$DIR/mysql/data" --skip-test-db >"$DIR/log/mariadb-install.log" 2>&1 \
    || die "mariadb-install-db failed"
fi
chown -R mysql:mysql "$DIR/mysql"
mariadbd --no-defaults --user=mysql --datadir="$DIR/mysql/data" --socket="$DIR/mysql/sock" --pid-file="$DIR/mysql/pid" \
  --bind-address=127.0.0.1 --port="$DB_PORT" --log-error="$DIR/mysql/err" >/dev/null 2>&1 &
wait_for 30 mariadb mariadb --no-defaults -S "$DIR/mysql/sock" -u root -e 'select 1'
mariadb --no-defaults -S "$DIR/mysql/sock" -u root -e "
  CREATE DATABASE IF NOT EXISTS slurm_acct_db;
  CREATE USER IF NOT EXISTS 'slurm'@'localhost' IDENTIFIED BY 'handxci';
  CREATE USER IF NOT EXISTS 'slurm'@'127.0.0.1' IDENTIFIED BY 'handxci';
  GRANT ALL ON slurm_acct_db.* TO 'slurm'@'localhost';
  GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';
  FLUSH PRIVILEGES;" || die "could not create the accounting database"

cat >"$DIR/etc/slurmdbd.conf" <<EOF
AuthType=auth/munge
DbdAddr=127.0.0.1
DbdHost=$HOST
DbdPort=$DBD_PORT
SlurmUser=slurm
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$DB_PORT
StorageUser=slurm
StoragePass=handxci
StorageLoc=slurm_acct_db
LogFile=$DIR/log/slurmdbd.log
PidFile=$DIR/run/slurmdbd.pid
EOF
chown slurm:slurm "$DIR/etc/slurmdbd.conf" && chmod 600 "$DIR/etc/slurmdbd.conf"

node=$(slurmd -C | head -n 1)
mem=$(echo "$node" | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p')
node=$(echo "$node" | sed "s/RealMemory=[0-9]*/RealMemory=$((mem * 95 / 100))/")
cat >"$DIR/etc/slurm.conf" <<EOF
ClusterName=handxci
SlurmctldHost=$HOST(127.0.0.1)
SlurmctldPort=$CTLD_PORT
SlurmdPort=$SLURMD_PORT
SlurmUser=slurm
AuthType=auth/munge
AuthInfo=cred_expire=10
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MailProg=/bin/true
SchedulerParameters=sched_interval=2,bf_interval=1
MinJobAge=3600
KillWait=2
ReturnToService=2
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=127.0.0.1
AccountingStoragePort=$DBD_PORT
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/run/slurmctld.pid
SlurmdPidFile=$DIR/run/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
$node NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$DIR/etc/slurm.conf"

slurmdbd >"$DIR/log/slurmdbd.out" 2>&1 || die "slurmdbd did not start"
wait_for 20 slurmdbd bash -c "exec 3<>/dev/tcp/127.0.0.1/$DBD_PORT"
slurmctld -c >"$DIR/log/slurmctld.out" 2>&1 || die "slurmctld did not start"
slurmd >"$DIR/log/slurmd.out" 2>&1 || die "slurmd did not start"
wait_for 30 "the node (sinfo idle)" bash -c 'sinfo -h -o %t | grep -qx idle'
wait_for 20 "accounting (sacctmgr)" bash -c 'sacctmgr -n show cluster format=cluster | grep -q handxci'
echo "SLURM_CONF=$SLURM_CONF"
