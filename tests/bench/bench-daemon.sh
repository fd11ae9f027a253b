#!/usr/bin/env bash
# SPDX-License-Identifier: GPL-3.0-or-later
# Runs bench-daemon (the first argument) after installing its baseline,
# redis-server and redis-tools (Debian packages), when they are missing
# (the benchmark starts its own redis-server on a free loopback port and
# stops it); then the rest of the arguments, a python and
# bench-daemon-attacks.py: daemon.status under the security reviews'
# attacks.
set -euo pipefail
if ! command -v redis-server >/dev/null || ! command -v redis-benchmark >/dev/null; then
	sudo=""
	[[ $(id -u) -ne 0 ]] && sudo="sudo"
	echo "installing redis-server redis-tools for the baseline" >&2
	export DEBIAN_FRONTEND=noninteractive
	$sudo apt-get update -qq >&2
	$sudo apt-get install -y -qq --no-install-recommends redis-server redis-tools >&2
fi
rc=0
"$1" || rc=1
shift
"$@" || rc=1
exit $rc
