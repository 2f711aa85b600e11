#!/usr/bin/zsh -f
# Completes LINE the way zsh does on Tab, in an interactive zsh on a pseudo-terminal (zpty) with
# compinit and kscfg's _kscfg from FPATH_DIR, and prints each candidate as
# "VALUE" or "VALUE -- DESCRIPTION". A compadd wrapper records what the completion functions add
# (the matching is zsh's own, through compadd -A).
# Usage: zsh -f zsh_complete.zsh FPATH_DIR LINE
zmodload zsh/zpty || exit 3
fpath_dir=$1
line=$2
setup=$(mktemp) || exit 3
trap 'rm -f $setup' EXIT
cat > $setup <<SETUP
PROMPT=''
RPROMPT=''
unsetopt zle_bracketed_paste 2>/dev/null
fpath=($fpath_dir \$fpath)
autoload -Uz compinit && compinit -u -D
bindkey '^M' undefined
bindkey '^J' undefined
bindkey '^I' complete-word
zstyle ':completion:*' list-grouped false
zstyle ':completion:*' insert-tab false
zmodload zsh/zutil
__mark() { print -r -- '<kscfg-mark>' }
compprefuncs=(__mark)
comppostfuncs=(__mark exit)
compadd() {
  if [[ \${@[1,(i)(-|--)]} == *-(O|A|D)\ * ]]; then
    builtin compadd "\$@"
    return \$?
  fi
  typeset -a __hits __dscr __tmp
  if (( \$@[(I)-d] )); then
    __tmp=\${@[\$[\${@[(i)-d]}+1]]}
    if [[ \$__tmp == \(* ]]; then eval "__dscr=\$__tmp"; else __dscr=( "\${(@P)__tmp}" ); fi
  fi
  builtin compadd -A __hits -D __dscr "\$@"
  [[ -n \$__hits ]] || return
  local i
  for i in {1..\$#__hits}; do
    local d=''
    (( \$#__dscr >= i )) && d=\${\${__dscr[\$i]##\$__hits[\$i] #}#-- }
    if [[ -n \$d ]]; then
      print -r -- "<kscfg-hit>\$__hits[\$i] -- \$d"
    else
      print -r -- "<kscfg-hit>\$__hits[\$i]"
    fi
  done
}
print -r -- '<kscfg-ready>'
SETUP
zpty z zsh -f -i
zpty -w z "source $setup"
out=''
while zpty -r z chunk; do
  out+=$chunk
  [[ $out == *'<kscfg-ready>'* ]] && break
done
zpty -w -n z "$line"$'\t'
marks=0
while zpty -r z chunk; do
  out+=$chunk
  [[ ${out#*<kscfg-ready>} == *'<kscfg-mark>'*'<kscfg-mark>'* ]] && break
done
zpty -d z
[[ -n $KSCFG_ZSH_DEBUG ]] && print -r -- "$out" >&2
for l in "${(@f)${out#*<kscfg-ready>}}"; do
  l=${l%$'\r'}
  [[ $l == '<kscfg-hit>'* ]] && print -r -- "${l#<kscfg-hit>}"
done
