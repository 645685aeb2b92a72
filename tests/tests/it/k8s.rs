//! deploy/k8s/sweep-job.yaml, checked offline: valid against the Kubernetes schemas
//! (kubernetes-validate's bundled schemas, strict, tests/python/k8s_manifest.py), and its
//! Indexed Job's pods given the shards 0 to K-1 of K by `hilbench sweep --shard auto` as it
//! reads their environment, written where the merge Job reads them.

use std::collections::BTreeMap;
use std::path::Path;

use hilbench::cli::{ShardArg, shard_arg};
use hilbench::sweep::shard::{self, Shard, ShardFrom};
use hilbench_tests::python::run_script;
use serde_json::Value;

fn manifest() -> Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/k8s/sweep-job.yaml");
    let out = run_script("k8s_manifest.py", &[&path.display().to_string()]);
    serde_json::from_str(out.trim()).expect("the script's JSON")
}

fn job<'a>(documents: &'a [Value], name: &str) -> &'a Value {
    documents
        .iter()
        .find(|d| d["kind"] == "Job" && d["metadata"]["name"] == name)
        .unwrap_or_else(|| panic!("no Job {name}"))
}

fn strings(v: &Value) -> Vec<&str> {
    v.as_array().expect("an array").iter().map(|s| s.as_str().expect("a string")).collect()
}

/// The value after `flag` in `args`.
fn flag<'a>(args: &[&'a str], flag: &str) -> &'a str {
    let at = args.iter().position(|a| *a == flag).unwrap_or_else(|| panic!("no {flag} in {args:?}"));
    args[at + 1]
}

#[test]
fn the_sweep_manifest_is_valid_against_the_kubernetes_schemas_and_its_pods_get_shards_0_to_k_of_shard_auto() {
    let v = manifest();
    assert_eq!(strings(&v["validated_against"]).len(), 2, "{v}");
    let documents = v["documents"].as_array().expect("documents");
    let sweep = job(documents, "hilbench-sweep");
    let spec = &sweep["spec"];
    assert_eq!(spec["completionMode"], "Indexed");
    let k = spec["completions"].as_u64().expect("completions");
    let container = &spec["template"]["spec"]["containers"][0];
    let args = strings(&container["args"]);
    let arg = shard_arg(flag(&args, "--shard")).expect("--shard");
    assert!(matches!(arg, ShardArg::Auto { .. }), "{arg:?}");
    assert!(flag(&args, "--runs").parse::<u64>().expect("--runs") >= k);
    assert_eq!(flag(&args, "--jobs"), container["resources"]["requests"]["cpu"].as_str().expect("cpu"));

    // The pod's environment: the manifest's values, and the index the Job sets.
    let mut env: BTreeMap<String, String> = BTreeMap::new();
    let mut index_vars = Vec::new();
    for var in container["env"].as_array().expect("env") {
        let name = var["name"].as_str().expect("a name").to_string();
        match var["value"].as_str() {
            Some(value) => {
                env.insert(name, value.to_string());
            }
            None => {
                let field = &var["valueFrom"]["fieldRef"]["fieldPath"];
                assert_eq!(
                    field, "metadata.annotations['batch.kubernetes.io/job-completion-index']",
                    "{name}"
                );
                index_vars.push(name);
            }
        }
    }
    let mut outs = Vec::new();
    for i in 0..k {
        let mut pod = env.clone();
        pod.insert(shard::K8S_INDEX.to_string(), i.to_string());
        assert_eq!(
            shard::resolve(arg, &pod),
            Ok(Shard { index: i, count: k, from: ShardFrom::Kubernetes }),
            "pod {i}"
        );
        // Kubernetes expands $(VAR) of a declared variable in the arguments.
        let mut out = flag(&args, "--out").to_string();
        for var in &index_vars {
            out = out.replace(&format!("$({var})"), &i.to_string());
        }
        outs.push(out);
    }
    // The merge reads every shard's directory, and no other.
    let merge = job(documents, "hilbench-sweep-merge");
    let merge_args = strings(&merge["spec"]["template"]["spec"]["containers"][0]["args"]);
    assert_eq!(merge_args[0], "sweep-merge");
    let out_at = merge_args.iter().position(|a| *a == "--out").expect("--out");
    assert_eq!(merge_args[1..out_at].to_vec(), outs.iter().map(String::as_str).collect::<Vec<_>>());
}
