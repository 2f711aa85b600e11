#!/bin/bash
# Completes LINE the way bash does on Tab, with Debian's bash-completion and kscfg's script, and
# prints the candidates (COMPREPLY), one per line.
# Usage: bash_complete.sh COMPLETION_SCRIPT LINE   (LINE ending in a space: a new, empty word)
set -u
source /usr/share/bash-completion/bash_completion
source "$1"
line=$2

# COMP_WORDS as readline makes them: blanks separate words, and a run of the other characters of
# COMP_WORDBREAKS (":", "=", ...) is a word of its own ("emu:" -> "emu" ":").
breaks=${COMP_WORDBREAKS//[$' \t\n\"\'']/}
words=()
w=''
kind=''  # '' nothing yet, 'w' word characters, 'b' break characters
for ((i = 0; i < ${#line}; i++)); do
  c=${line:i:1}
  if [[ $c == [[:blank:]] ]]; then
    [[ -n $kind ]] && words+=("$w")
    w=''
    kind=''
  elif [[ $breaks == *"$c"* ]]; then
    [[ $kind == w ]] && { words+=("$w"); w=''; }
    w+=$c
    kind=b
  else
    [[ $kind == b ]] && { words+=("$w"); w=''; }
    w+=$c
    kind=w
  fi
done
words+=("$w")  # the word under the cursor ('' after a blank)

COMP_WORDS=("${words[@]}")
COMP_CWORD=$((${#words[@]} - 1))
COMP_LINE=$line
COMP_POINT=${#line}
COMP_TYPE=9
COMP_KEY=9
prev=''
((COMP_CWORD > 0)) && prev=${COMP_WORDS[COMP_CWORD - 1]}
_kscfg kscfg "${COMP_WORDS[COMP_CWORD]}" "$prev"
printf '%s\n' "${COMPREPLY[@]}"
