# syntax=docker/dockerfile:1
# tanklab: one image for the three tiers and the historian (plant, plc, supervisor, historian);
# the command picks the tier.
#
#   docker build -t tanklab:latest .
#   docker run --rm -p 4840:4840 tanklab:latest plant          (see docs/docker.md, docker-compose.yml)
#
# Stage 1 builds the project's wheel and installs it with its runtime dependencies into
# /opt/venv (docker/install.sh: the same script tests/test_docker.py runs in a fresh venv).
# Every dependency comes as a binary wheel, so neither stage installs a compiler. Stage 2 gets
# only /opt/venv and configs/ and runs as an unprivileged user.
#
# BASE_IMAGE (both stages; default python:3.11-slim): any Debian-like image with python3 (3.11),
# its venv module, pip, groupadd and useradd, e.g. a local stand-in built with debootstrap where
# no registry is reachable (docs/docker.md; docker-compose.yml passes $TANKLAB_BASE_IMAGE).
# docker/pip-ca.crt, when present (never in git: docs/docker.md), is the CA bundle pip in the
# builder stage trusts (a site whose TLS is intercepted); it stays in the builder stage.

ARG BASE_IMAGE=python:3.11-slim

FROM ${BASE_IMAGE} AS builder
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore
WORKDIR /src
COPY docker/ /usr/local/share/tanklab-docker/
COPY pyproject.toml ./
# The dependencies in a layer of their own: a change to src/ (or README.md) reuses it.
RUN sh /usr/local/share/tanklab-docker/install.sh --deps-only /src /opt/venv
COPY README.md ./
COPY src ./src
RUN sh /usr/local/share/tanklab-docker/install.sh /src /opt/venv /tmp/wheels

FROM ${BASE_IMAGE}
# TANKLAB_HOST=0.0.0.0: a tier in a container must listen on every interface to be reachable
# from the other containers and through the published ports (the CLI's default is 127.0.0.1).
# TANKLAB_HOME: where the certificates, the tier's key and the users file are mounted read-only
# (docker-compose.yml); the image holds no key and no password. The audit log goes to the
# writable volume.
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    TANKLAB_HOST=0.0.0.0 \
    TANKLAB_HOME=/etc/tanklab \
    TANKLAB_AUDIT_DIR=/var/lib/tanklab/audit
# uid/gid 10001: outside the range of host accounts; /var/lib/tanklab holds a tier's state file
# or the historian's store (a volume per service in docker-compose.yml), the only place the user
# may write.
RUN groupadd --system --gid 10001 tanklab \
 && useradd --system --uid 10001 --gid tanklab --no-create-home --home-dir /app \
        --shell /usr/sbin/nologin tanklab \
 && install -d -o tanklab -g tanklab -m 0750 /var/lib/tanklab
COPY --from=builder /opt/venv /opt/venv
WORKDIR /app
COPY configs ./configs
USER tanklab
EXPOSE 4840 4841 4842 4843
ENTRYPOINT ["tankctl"]
CMD ["plant"]
