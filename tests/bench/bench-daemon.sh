#!/usr/bin/env bash
# SPDX-License-Identifier: GPL-3.0-or-later
# Runs bench-daemon after installing its baseline, redis-server and
# redis-tools (Debian packages), when they are missing. The benchmark
# starts its own redis-server on a free loopback port and stops it.
set -euo pipefail
if ! command -v redis-server >/dev/null || ! command -v redis-benchmark >/dev/null; then
	sudo=""
	[[ $(id -u) -ne 0 ]] && sudo="sudo"
	echo "installing redis-server redis-tools for the baseline" >&2
	export DEBIAN_FRONTEND=noninteractive
	$sudo apt-get update -qq >&2
	$sudo apt-get install -y -qq --no-install-recommends redis-server redis-tools >&2
fi
exec "$@"
