#!/usr/bin/env bash
# Validates deploy/ without a cluster: the Kubernetes manifests against the
# API's schemas (kubernetes-validate, from PyPI; the kustomize output too
# when kubectl is here) and the nginx configs with `nginx -t` (Debian's
# nginx). .ci/run runs it; it needs python3 with pip, and nginx.
set -euo pipefail
cd "$(dirname "$0")"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
K8S_VERSION=1.31.0

validate=kubernetes-validate
if ! command -v kubernetes-validate > /dev/null; then
  # In a virtual environment of its own: a system Python may refuse
  # packages from pip (PEP 668).
  python3 -m venv "$tmp/venv"
  "$tmp/venv/bin/pip" install --quiet --disable-pip-version-check kubernetes-validate==1.31.0
  validate="$tmp/venv/bin/kubernetes-validate"
fi
echo "== kubernetes manifests (schemas of Kubernetes $K8S_VERSION)"
"$validate" --quiet --strict -k "$K8S_VERSION" k8s/*.yaml
if command -v kubectl > /dev/null; then
  kubectl kustomize . > "$tmp/all.yaml"
  "$validate" --quiet --strict -k "$K8S_VERSION" "$tmp/all.yaml"
  echo "kustomize output: $(grep -c '^kind:' "$tmp/all.yaml") objects valid"
else
  echo "(no kubectl here: the kustomization's generated ConfigMaps are not checked)"
fi

NGINX_BIN=${NGINX_BIN:-$(command -v nginx || echo /usr/sbin/nginx)}
echo "== nginx configs ($("$NGINX_BIN" -v 2>&1))"
# The cluster's config as it is, but for what Debian's nginx (1.22) cannot
# check here: `resolve` on an upstream server needs nginx >= 1.27.3 (the
# image deploy/k8s/nginx.yaml runs), and the cluster's DNS names do not
# resolve outside a cluster (each replica's becomes a loopback address of
# its own). Those are replaced; every other
# line, the shared includes among them, is checked as deployed.
mkdir -p "$tmp/pvsd" "$tmp/logs"
cp nginx/*.conf "$tmp/pvsd/"
sed -e "s#/tmp/#$tmp/#g" \
    -e "s#/etc/nginx/pvsd/#$tmp/pvsd/#g" \
    -e 's# resolve max_fails# max_fails#' \
    -e 's#pvsd-\([0-9]*\)\.pvsd\.pvsd\.svc\.cluster\.local#127.0.1.\1#' \
    -e 's#^\( *resolver\) kube-dns\.kube-system\.svc\.cluster\.local#\1 127.0.0.1#' \
    nginx/nginx.conf > "$tmp/pvsd/nginx.conf"
grep -q "hash \$pvsd_key consistent" "$tmp/pvsd/nginx.conf"
# Every replica by a name of its own (the ring places servers by name).
[ "$(grep -c 'server pvsd-[0-9]*\.pvsd\.pvsd\.svc\.cluster\.local:8080 resolve' nginx/nginx.conf)" -ge 3 ]
"$NGINX_BIN" -t -q -p "$tmp" -e "$tmp/logs/error.log" -c "$tmp/pvsd/nginx.conf"
echo "nginx/nginx.conf: syntax ok"
