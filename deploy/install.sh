#!/usr/bin/env bash
# Installs the motm stack as systemd units: the binaries, the config folder, the iceoryx2
# config, one argument file per process, the motm@.service template with its drop-ins and
# motm.target. See deploy/README.md for setting a robot up from scratch.
#
#   sudo deploy/install.sh                       # build first: cargo build --release --workspace
#   deploy/install.sh --prefix /tmp/m/opt --confdir /tmp/m/etc --unitdir /tmp/m/units \
#       --bin-dir target/debug --no-user --no-enable --link   # a trial install anywhere
set -euo pipefail

repo=$(cd "$(dirname "$0")/.." && pwd)
prefix=/opt/motm
confdir=/etc/motm
unitdir=/etc/systemd/system
stack=frankie
bin_src="$repo/target/release"
service_user=motm
make_user=1
enable=1
link=0

usage() {
  sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'
  cat <<EOF
options:
  --prefix DIR     binaries go to DIR/bin (default $prefix)
  --confdir DIR    config, iceoryx2.toml and argument files (default $confdir)
  --unitdir DIR    systemd units (default $unitdir)
  --stack NAME     stack config in config/ (default $stack)
  --bin-dir DIR    where the built binaries are (default target/release)
  --user NAME      the one user every process runs as (default $service_user)
  --no-user        do not create the user
  --no-enable      do not run systemctl (daemon-reload, enable motm.target)
  --link           symlink the binaries instead of copying them
EOF
}

while [[ $# -gt 0 ]]; do
  case "$1" in
    --prefix) prefix=$2; shift 2 ;;
    --confdir) confdir=$2; shift 2 ;;
    --unitdir) unitdir=$2; shift 2 ;;
    --stack) stack=$2; shift 2 ;;
    --bin-dir) bin_src=$(cd "$2" && pwd); shift 2 ;;
    --user) service_user=$2; shift 2 ;;
    --no-user) make_user=0; shift ;;
    --no-enable) enable=0; shift ;;
    --link) link=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "install.sh: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
done

stack_file="$repo/config/$stack.toml"
if [[ ! -f "$stack_file" ]]; then
  echo "install.sh: no stack config $stack_file (--stack)" >&2
  exit 2
fi
# Every process of the stack config plus the supervisor; the logger has a unit too (started on
# its own: `systemctl start motm@logger.service`), and `motm` is the command line (`motm status`).
processes=(supervisor $(sed -n 's/^name = "\([a-z0-9-]*\)".*/\1/p' "$stack_file"))
binaries=("${processes[@]}" logger motm)
for p in "${binaries[@]}"; do
  if [[ ! -x "$bin_src/$p" ]]; then
    echo "install.sh: $bin_src/$p missing: build with 'cargo build --release --workspace' (or give --bin-dir)" >&2
    exit 2
  fi
done

# One service user for every process: iceoryx2's shared memory and records are owner-only.
if [[ $make_user == 1 ]] && ! id "$service_user" >/dev/null 2>&1; then
  useradd --system --no-create-home --shell /usr/sbin/nologin "$service_user"
fi

install -d "$prefix/bin" "$confdir/env" "$unitdir"
for p in "${binaries[@]}"; do
  if [[ $link == 1 ]]; then
    ln -sf "$bin_src/$p" "$prefix/bin/$p"
  else
    install -m 0755 "$bin_src/$p" "$prefix/bin/$p"
  fi
done
rm -rf "$confdir/config"
cp -r "$repo/config" "$confdir/config"
install -m 0644 "$repo/config/iceoryx2.toml" "$confdir/iceoryx2.toml"
install -m 0644 "$repo/deploy/README.md" "$confdir/README.md"

# Each process's arguments, expanded from the stack config by the supervisor itself.
"$bin_src/supervisor" --stack "$stack" --config-dir "$confdir/config" --print-launch \
  | while IFS=$'\t' read -r name args; do
      printf 'MOTM_ARGS="%s"\n' "$args" > "$confdir/env/$name.env"
    done
# Under systemd the units run the processes; the supervisor runs the mission only.
printf 'MOTM_ARGS="--stack %s --config-dir %s/config --no-spawn"\n' "$stack" "$confdir" \
  > "$confdir/env/supervisor.env"
# The logger records every topic to an MCAP file in its state directory (/var/lib/motm, see
# motm@logger.service.d/); a restart starts the file again.
robot=$(sed -n 's/^robot = "\([a-z0-9_]*\)".*/\1/p' "$stack_file")
printf 'MOTM_ARGS="--out /var/lib/motm/stack.mcap --config-dir %s/config --robot %s"\n' "$confdir" "$robot" \
  > "$confdir/env/logger.env"

# Units: the template, its per-process drop-ins, the target; with the paths filled in.
subst() {
  sed -e "s|@BINDIR@|$prefix/bin|g" -e "s|@CONFDIR@|$confdir|g" \
      -e "s|^User=motm$|User=$service_user|" -e "s|^Group=motm$|Group=$service_user|" "$1" > "$2"
}
subst "$repo/deploy/systemd/motm@.service" "$unitdir/motm@.service"
subst "$repo/deploy/systemd/motm.target" "$unitdir/motm.target"
for dropin in "$repo"/deploy/systemd/*.service.d; do
  name=$(basename "$dropin")
  install -d "$unitdir/$name"
  for conf in "$dropin"/*.conf; do
    subst "$conf" "$unitdir/$name/$(basename "$conf")"
  done
done

if [[ $enable == 1 ]]; then
  systemctl daemon-reload
  systemctl enable motm.target
  echo "installed; start with: systemctl start motm.target"
else
  echo "installed under $prefix, $confdir and $unitdir (systemctl not run)"
fi
