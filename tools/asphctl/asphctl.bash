# SPDX-License-Identifier: GPL-3.0-or-later
# bash completion for asphctl
_asphctl()
{
	local cur prev words cword
	_init_completion 2>/dev/null || {
		cur=${COMP_WORDS[COMP_CWORD]}
		prev=${COMP_WORDS[COMP_CWORD-1]}
		words=("${COMP_WORDS[@]}")
		cword=$COMP_CWORD
	}
	local commands="submit status watch cancel pause resume requeue list result queue instruments drivers backup health"
	local cmd="" i
	for ((i = 1; i < cword; i++)); do
		case ${words[i]} in
		-s|--socket) ((i++)) ;;
		-*) ;;
		*) cmd=${words[i]}; break ;;
		esac
	done
	case $prev in
	-s|--socket|--out) COMPREPLY=($(compgen -f -- "$cur")); return ;;
	--method) COMPREPLY=($(compgen -W "op ot lb ci raster concentric spiral fermat" -- "$cur")); return ;;
	--residual) COMPREPLY=($(compgen -W "normal sag" -- "$cur")); return ;;
	--state) COMPREPLY=($(compgen -W "queued running paused completed failed cancelled interrupted" -- "$cur")); return ;;
	esac
	if [[ -z $cmd ]]; then
		COMPREPLY=($(compgen -W "$commands --socket --json --help --version" -- "$cur"))
		return
	fi
	local opts="--json --help"
	case $cmd in
	submit) opts+=" --method --h --spacing --points --instrument --priority --label --dof --residual --robust --zernike --wait"
		if [[ $cur != -* ]]; then
			COMPREPLY=($(compgen -W "weak strong turning-point" -- "$cur") $(compgen -f -- "$cur"))
			return
		fi ;;
	status) opts+=" --history" ;;
	requeue) opts+=" --restart" ;;
	list) opts+=" --state --instrument --label --mine --limit --offset" ;;
	result) opts+=" --out" ;;
	backup) [[ $cur != -* ]] && { COMPREPLY=($(compgen -f -- "$cur")); return; } ;;
	health) opts+=" --timeout" ;;
	queue) opts+=" --abort"
		[[ $cur != -* ]] && { COMPREPLY=($(compgen -W "show move start stop" -- "$cur")); return; } ;;
	esac
	COMPREPLY=($(compgen -W "$opts" -- "$cur"))
}
complete -F _asphctl asphctl
