//! The deployment files say what they do: the Kubernetes manifest pins its image and bounds its
//! CPU (the worker count follows the cgroup's quota), and every `Documentation=` file of the
//! systemd unit is installed by the unit's own install steps and shipped in the image.

use std::path::Path;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn read(p: &str) -> String {
    std::fs::read_to_string(Path::new(ROOT).join(p)).unwrap()
}

#[test]
fn kubernetes_pins_the_image_and_limits_cpu() {
    let k8s = read("deploy/kubernetes/gatewatch.yaml");
    let image = k8s
        .lines()
        .find_map(|l| l.trim().strip_prefix("image: "))
        .expect("an image");
    let tag = image.rsplit_once(':').map(|x| x.1).expect("a tag");
    assert!(tag != "latest" && !tag.is_empty(), "image {image}");
    assert!(k8s.contains("imagePullPolicy: IfNotPresent"));
    let limits = k8s
        .lines()
        .find_map(|l| l.trim().strip_prefix("limits: "))
        .expect("resource limits");
    assert!(
        limits.contains("cpu:") && limits.contains("memory:"),
        "{limits}"
    );
}

#[test]
fn systemd_documentation_is_installed() {
    let unit = read("deploy/systemd/gatewatch.service");
    let docs: Vec<&str> = unit
        .lines()
        .filter_map(|l| l.strip_prefix("Documentation="))
        .flat_map(|l| l.split_whitespace())
        .collect();
    assert!(!docs.is_empty());
    let install = unit
        .lines()
        .find(|l| l.contains("/usr/share/doc/gatewatch") && l.starts_with("#   install"))
        .expect("an install step for the documentation");
    let dockerfile = read("Dockerfile");
    for d in docs {
        let file = d
            .strip_prefix("file:///usr/share/doc/gatewatch/")
            .unwrap_or_else(|| panic!("{d}: not under /usr/share/doc/gatewatch"));
        let source = if file == "README.md" {
            file.to_string()
        } else {
            format!("docs/{file}")
        };
        assert!(
            Path::new(ROOT).join(&source).exists(),
            "{source} is missing"
        );
        let glob = if file == "README.md" {
            "README.md"
        } else {
            "docs/*.md"
        };
        assert!(
            install.contains(glob),
            "the install step does not install {source}"
        );
        assert!(
            dockerfile.contains(glob),
            "the image does not ship {source}"
        );
    }
}

/// The Kubernetes store's volume holds the store's bound: past an emptyDir's `sizeLimit` the
/// kubelet evicts the pod and the volume goes with it (history, alert states, outbox). The
/// ConfigMap left the default bound of 12 288 MiB on a 5Gi volume, which 16 gates fill in 11
/// days.
#[test]
fn kubernetes_store_bound_fits_its_volume() {
    let k8s = read("deploy/kubernetes/gatewatch.yaml");
    let mut lines = k8s.lines().skip_while(|l| l.trim() != "gatewatch.toml: |");
    lines.next().expect("ConfigMap has gatewatch.toml");
    let toml_text: String = lines
        .take_while(|l| !l.starts_with("---"))
        .map(|l| l.trim_start().to_string() + "\n")
        .collect();
    let config: toml::Table = toml_text.parse().expect("the ConfigMap's TOML parses");
    let mb = config
        .get("storage")
        .and_then(|s| s.get("max_size_mb"))
        .and_then(|v| v.as_integer())
        .expect("the ConfigMap sets [storage] max_size_mb for its volume") as u64;
    let limit = k8s
        .lines()
        .skip_while(|l| l.trim() != "- name: state")
        .find_map(|l| l.split_once("sizeLimit: ").map(|x| x.1))
        .expect("the state volume's sizeLimit");
    let gib: u64 = limit
        .trim_end_matches(['}', ' '])
        .strip_suffix("Gi")
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("sizeLimit {limit}: expected NGi"));
    let bound = mb << 20;
    let wal = gatewatch::store::wal_budget(bound);
    assert!(
        bound + wal <= gib << 30,
        "max_size_mb {mb} plus the WAL's {} MiB exceeds the volume's {gib}Gi",
        wal >> 20
    );
}

/// The probes and the scrape go to the health listener the ConfigMap opens: the probes name
/// the container port `health`, whose number is `server.health_listen`'s port, and the scrape
/// annotation and the NetworkPolicy use that number too. A probe on the main port is refused
/// with everything else when clients hold its connections, and the kubelet restarts the pod.
#[test]
fn kubernetes_probes_and_scrape_use_the_health_listener() {
    let k8s = read("deploy/kubernetes/gatewatch.yaml");
    let health_listen = k8s
        .lines()
        .find_map(|l| l.trim().strip_prefix("health_listen = "))
        .expect("the ConfigMap sets server.health_listen");
    let port = health_listen
        .trim_matches('"')
        .rsplit_once(':')
        .map(|x| x.1)
        .expect("an address with a port");
    assert!(
        k8s.contains(&format!("- {{name: health, containerPort: {port}}}")),
        "a container port `health` = {port}"
    );
    for probe in ["livenessProbe", "readinessProbe"] {
        let get = k8s
            .lines()
            .skip_while(|l| l.trim() != format!("{probe}:"))
            .nth(1)
            .unwrap_or_else(|| panic!("a {probe}"));
        assert!(get.contains("port: health"), "{probe}: {get}");
    }
    assert!(k8s.contains(&format!("prometheus.io/port: \"{port}\"")));
    assert!(k8s.contains(&format!("- {{port: {port}, protocol: TCP}}")));
}
