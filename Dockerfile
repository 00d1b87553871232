# syntax=docker/dockerfile:1
# tanklab: one image for the three tiers (plant, plc, supervisor); the command picks the tier.
#
#   docker build -t tanklab:latest .
#   docker run --rm -p 4840:4840 tanklab:latest plant          (see docs/docker.md, docker-compose.yml)
#
# Stage 1 builds the project's wheel and installs it with its runtime dependencies into
# /opt/venv (docker/install.sh: the same script tests/test_docker.py runs in a fresh venv).
# Every dependency comes as a binary wheel, so neither stage installs a compiler. Stage 2 gets
# only /opt/venv and configs/ and runs as an unprivileged user.

FROM python:3.11-slim AS builder
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore
WORKDIR /src
COPY docker/install.sh /usr/local/bin/tanklab-install
COPY pyproject.toml README.md ./
COPY src ./src
RUN sh /usr/local/bin/tanklab-install /src /opt/venv /tmp/wheels

FROM python:3.11-slim
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
# uid/gid 10001: outside the range of host accounts; /var/lib/tanklab holds the plant's state
# file (a volume in docker-compose.yml), the only place the user may write.
RUN groupadd --system --gid 10001 tanklab \
 && useradd --system --uid 10001 --gid tanklab --no-create-home --home-dir /app \
        --shell /usr/sbin/nologin tanklab \
 && install -d -o tanklab -g tanklab -m 0750 /var/lib/tanklab
COPY --from=builder /opt/venv /opt/venv
WORKDIR /app
COPY configs ./configs
USER tanklab
EXPOSE 4840 4841 4842
ENTRYPOINT ["tankctl"]
CMD ["plant"]
