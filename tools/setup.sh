#!/usr/bin/env bash
# Installs the Debian packages listed in tools/debian-packages.txt that are missing, then creates the catkin
# workspace .ws/ inside the repository, its package folder made of links to the repository's entries. Safe to run
# repeatedly: it does nothing when everything is in place.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)

missing=()
while read -r package; do
  [[ -z "$package" || "$package" == \#* ]] && continue
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || missing+=("$package")
done < "$root/tools/debian-packages.txt"

if ((${#missing[@]})); then
  echo "setup: installing missing Debian packages: ${missing[*]}"
  sudo_cmd=()
  [[ $(id -u) -eq 0 ]] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

mkdir -p "$root/.ws/src"
# catkin records the test environment when it first configures and keeps only folders that exist then: without this
# one the Python tests and rosservice cannot import the package's generated messages on a fresh clone.
mkdir -p "$root/.ws/devel/lib/python3/dist-packages"
# The package's folder in the workspace links every entry of the repository except .ws and .git. A link to the
# repository itself would put the workspace inside its own package: rosrun searches the package with `find -L` and
# printed "File system loop detected" on every run. An earlier checkout's link to the whole repository is replaced,
# and links to entries that are gone are removed.
package="$root/.ws/src/muscle_deformation"
[[ -L "$package" ]] && rm "$package"
mkdir -p "$package"
shopt -s nullglob dotglob
for entry in "$root"/*; do
  name=$(basename "$entry")
  [[ "$name" == .ws || "$name" == .git ]] && continue
  ln -sfn "$entry" "$package/$name"
done
for link in "$package"/*; do
  [[ -L "$link" && ! -e "$link" ]] && rm "$link"
done
shopt -u nullglob dotglob
