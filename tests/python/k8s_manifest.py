"""Validates a Kubernetes manifest offline against the Kubernetes schemas that
kubernetes-validate bundles (strict: a key the schema does not have is an error), for the oldest
and the newest version it bundles, and prints its documents as one JSON array for the Rust test
to read (tests/tests/it/k8s.rs). Exits 1 naming the resource and the error when one does not
validate."""

import json
import sys

import kubernetes_validate
import yaml
from kubernetes_validate import utils


def main() -> int:
    path = sys.argv[1]
    with open(path, encoding="utf-8") as f:
        documents = [d for d in yaml.safe_load_all(f) if d is not None]
    versions = sorted(utils.all_versions(), key=lambda v: tuple(int(x) for x in v.split(".")))
    oldest, newest = versions[0], versions[-1]
    failed = False
    for doc in documents:
        name = f"{doc.get('kind')}/{doc.get('metadata', {}).get('name')}"
        for version in (oldest, newest):
            try:
                kubernetes_validate.validate(doc, version, strict=True)
            except kubernetes_validate.ValidationError as e:
                path_in = ".".join(str(p) for p in e.path)
                print(f"{path}: {name} against Kubernetes {version}: {path_in}: {e.message}", file=sys.stderr)
                failed = True
            except kubernetes_validate.SchemaNotFoundError as e:
                print(f"{path}: {name} against Kubernetes {version}: no schema: {e}", file=sys.stderr)
                failed = True
    if failed:
        return 1
    print(json.dumps({"validated_against": [oldest, newest], "documents": documents}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
