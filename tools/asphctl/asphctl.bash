# SPDX-License-Identifier: GPL-3.0-or-later
# bash completion for asphctl. The commands and each command's options come
# from asphctl itself (`asphctl --help`, `asphctl help COMMAND`), so they are
# the ones the installed asphctl has.
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
	-s|--socket|--out|--report|--tolerance) COMPREPLY=($(compgen -f -- "$cur")); return ;;
	--method) COMPREPLY=($(compgen -W "op ot lb ci raster concentric spiral fermat cvt" -- "$cur")); return ;;
	--residual) COMPREPLY=($(compgen -W "normal sag" -- "$cur")); return ;;
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
			COMPREPLY=($(compgen -W "weak strong turning-point" -- "$cur") $(compgen -f -- "$cur"))
			return
		fi ;;
	queue)
		[[ $cur != -* ]] && { COMPREPLY=($(compgen -W "show move start stop" -- "$cur")); return; } ;;
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
