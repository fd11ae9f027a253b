# SPDX-License-Identifier: GPL-3.0-or-later
# bash completion for asphctl. The commands, each command's options and the
# values that come from a table (presets, plan methods, residuals, the
# formats of measured data, the queue's subcommands) come from asphctl
# itself (`asphctl --help`, `asphctl help COMMAND`), so they are the ones
# the installed asphctl has. The job states are the protocol's
# (proto/schema/common.json, jobState).

# The text of an operand or option in `asphctl help COMMAND`, its lines
# joined: _asphctl_item submit '--method M'.
_asphctl_item()
{
	asphctl help "$1" 2>/dev/null | awk -v t="  $2 " '
		index($0, t) == 1 { s = substr($0, length(t) + 1); sub(/^ +/, "", s); on = 1; next }
		on && /^                      [^ ]/ { sub(/^ +/, ""); s = s " " $0; next }
		{ on = 0 }
		END { print s }'
}

_asphctl()
{
	local cur prev words cword
	_init_completion 2>/dev/null || {
		cur=${COMP_WORDS[COMP_CWORD]}
		prev=${COMP_WORDS[COMP_CWORD-1]}
		words=("${COMP_WORDS[@]}")
		cword=$COMP_CWORD
	}
	local cmd="" i
	for ((i = 1; i < cword; i++)); do
		case ${words[i]} in
		-s|--socket) ((i++)) ;;
		-*) ;;
		*) cmd=${words[i]}; break ;;
		esac
	done
	case $prev in
	-s|--socket|--out|--report|--tolerance|--measured) COMPREPLY=($(compgen -f -- "$cur")); return ;;
	--method) COMPREPLY=($(compgen -W "$(_asphctl_item submit '--method M' | tr -d ,)" -- "$cur")); return ;;
	--format) COMPREPLY=($(compgen -W "$(_asphctl_item submit '--format F' | tr -d ,)" -- "$cur")); return ;;
	--units) COMPREPLY=($(compgen -W "$(_asphctl_item submit '--units U' | tr -d ,)" -- "$cur")); return ;;
	--residual)
		COMPREPLY=($(compgen -W "$(asphctl help submit 2>/dev/null |
			grep -o -- '--residual [a-z|-]*' | cut -d' ' -f2 | tr '|' ' ')" -- "$cur"))
		return ;;
	--state) COMPREPLY=($(compgen -W "queued running paused completed failed cancelled interrupted" -- "$cur")); return ;;
	esac
	if [[ -z $cmd ]]; then
		local commands
		commands=$(asphctl --help 2>/dev/null | sed -n '/^Commands:/,/^$/{/^  /s/^  \([a-z]*\).*/\1/p}')
		COMPREPLY=($(compgen -W "$commands --socket --json --help --version" -- "$cur"))
		return
	fi
	case $cmd in
	submit)
		if [[ $cur != -* ]]; then
			COMPREPLY=($(compgen -W "$(_asphctl_item submit LENS | sed 's/^[^(]*(\([^)]*\)).*/\1/' | tr -d ,)" -- "$cur")
				   $(compgen -f -- "$cur"))
			return
		fi ;;
	queue)
		[[ $cur != -* ]] && { COMPREPLY=($(compgen -W "$(asphctl help queue 2>/dev/null |
			sed -n '1s/^Usage: asphctl queue //p' | grep -o '\(\[\||\) *[a-z][a-z]*' |
			tr -d '[| ')" -- "$cur")); return; } ;;
	backup)
		[[ $cur != -* ]] && { COMPREPLY=($(compgen -f -- "$cur")); return; } ;;
	help)
		[[ $cur != -* ]] && { COMPREPLY=($(compgen -W "$(asphctl --help 2>/dev/null | sed -n '/^Commands:/,/^$/{/^  /s/^  \([a-z]*\).*/\1/p}') exit-status" -- "$cur")); return; } ;;
	esac
	local opts
	opts=$({ asphctl help "$cmd" 2>/dev/null | sed -n '/^Usage:/,/^$/p' |
		 grep -o -- '--[a-z][a-z-]*'; echo --json; echo --help; } | sort -u)
	COMPREPLY=($(compgen -W "$opts" -- "$cur"))
}
complete -F _asphctl asphctl
