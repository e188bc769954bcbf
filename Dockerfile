# Multi-stage build of the gatewatch daemon.
#   docker build -t gatewatch .
#   docker run -p 9464:9464 -p 8094:8094 -e GATEWATCH_TCP_LISTEN=0.0.0.0:8094 \
#       -e GATEWATCH_TCP_ALLOWED_NETWORKS=10.20.0.0/16,172.17.0.1 gatewatch
# The raw TCP port has no tokens: only `tcp_allowed_networks` may use it (loopback by default).
# With rootful Docker a client on another host reaches a published port through iptables' DNAT
# and keeps its own source address: list the sensors' networks (10.20.0.0/16 above), not the
# bridge's. Only a client on the Docker host itself (to 127.0.0.1:8094, through docker-proxy)
# arrives from the bridge's gateway (172.17.0.1 on the default bridge), and another container
# from its own bridge address. Rootless Docker or Podman may hide the source address, depending
# on their port driver. A refused client is logged with the address gatewatch sees. Without
# the second variable every client but loopback is refused, and `serve` warns at start.
#
# HEALTHCHECK: debian:bookworm-slim has no curl or wget, so none is declared here; use the
# orchestrator's HTTP probes on /healthz (liveness) and /readyz (readiness) instead (see
# deploy/kubernetes/gatewatch.yaml), or install curl and add
#   HEALTHCHECK CMD curl -fsS http://127.0.0.1:9464/healthz || exit 1

FROM rust:1-bookworm AS builder
WORKDIR /src
# the whole context (see .dockerignore), so every target Cargo.toml declares is present
COPY . .
# Without DWARF: Cargo.toml's release profile keeps line tables for profiling (`debug = 1`),
# which made the image's binary 173 MB; without them about 30 MB (`strip --strip-debug` of
# the same build), and a panic's backtrace still names its functions (the symbol table stays).
ENV CARGO_PROFILE_RELEASE_DEBUG=0 CARGO_PROFILE_RELEASE_STRIP=debuginfo
RUN cargo build --release --locked --bin gatewatch

FROM debian:bookworm-slim
RUN apt-get update \
    && apt-get install -y --no-install-recommends ca-certificates \
    && rm -rf /var/lib/apt/lists/* \
    && useradd --system --uid 10001 --no-create-home --shell /usr/sbin/nologin gatewatch \
    && install -d -o gatewatch -g gatewatch -m 0700 /var/lib/gatewatch
COPY --from=builder /src/target/release/gatewatch /usr/local/bin/gatewatch
COPY config/gatewatch.toml /etc/gatewatch/gatewatch.toml
COPY README.md docs/*.md /usr/share/doc/gatewatch/
USER gatewatch
# 9464: HTTP API, ingestion and /metrics; 8094: raw TCP line protocol (when tcp_listen is set);
# 9465: the probes and /metrics alone (when health_listen is set, e.g.
# -e GATEWATCH_HEALTH_LISTEN=0.0.0.0:9465: docs/security.md, "Exhaust connections")
EXPOSE 9464 8094 9465
ENV GATEWATCH_LOG_FORMAT=json
# The store (history, alert state, notification outbox): mount a volume here so it outlives
# the container (docs/operations.md, "The store").
ENV GATEWATCH_STORAGE_PATH=/var/lib/gatewatch/gatewatch.db
VOLUME /var/lib/gatewatch
ENTRYPOINT ["/usr/local/bin/gatewatch"]
CMD ["serve", "--config", "/etc/gatewatch/gatewatch.toml"]
