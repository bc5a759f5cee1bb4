#!/usr/bin/env bash
# Debian packages the backends need: Mesa EGL for headless OpenGL (annotation engine, photo
# baseline) and LLVM 19 for Mitsuba's llvm_ad_rgb variant (Debian's default LLVM 14/15 aborts);
# and Sweet Home 3D's furniture library (CC0 / CC-BY 3.0 models for the furnished scenes).
set -euo pipefail
pkgs=(libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 libllvm19 libxkbcommon0 libsm6 libxi6 libxxf86vm1 libxfixes3 libxrender1 libgomp1 sweethome3d-furniture)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then exit 0; fi
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
echo "installing Debian packages: ${missing[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
