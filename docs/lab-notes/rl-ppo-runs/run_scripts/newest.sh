# Sourced by side_by_side.sh and merge_call.sh.
newest() {  # the COUNT newest files named PATTERN under the current directory, oldest first
  find . -name "$1" -printf '%T@ %p\n' | sort -n | tail -"$2" | cut -d' ' -f2-
}
