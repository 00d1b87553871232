"""``tankctl k8s``: what deploy/kubernetes/ needs from a tanklab home (docs/kubernetes.md).

::

    tankctl k8s secrets [--home PATH] [--namespace NS] [--name-prefix P] [--output DIR]

renders the Secrets the manifests reference (:mod:`tankctl.k8s`): ``P-pki`` (certificates,
trust list, CRL), ``P-users`` (the users file) and ``P-key-ID`` (one private key each), as a
YAML stream on stdout for ``kubectl apply -f -``, or with ``--output DIR`` one file per Secret
(0600, in a 0700 directory) plus a ``kustomization.yaml`` listing them (``kubectl apply -k DIR``).
Nothing is ever rendered as a ConfigMap. An incomplete home or an invalid name: one line
``tankctl: ...`` on stderr, exit 2, nothing written. Imports no asyncua (decision 0044).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from tankctl.usage import OneLineUsage

__all__ = ["k8s_app"]

k8s_app = typer.Typer(help="Kubernetes: the Secrets deploy/kubernetes/ references.", no_args_is_help=True)


@k8s_app.command("secrets", cls=OneLineUsage)
def k8s_secrets(
    home: Annotated[
        Path | None,
        typer.Option(
            "--home",
            help="Security home (env TANKLAB_HOME; default $XDG_CONFIG_HOME/tanklab or ~/.config/tanklab).",
        ),
    ] = None,
    namespace: Annotated[
        str | None,
        typer.Option("--namespace", "-n", help="metadata.namespace of each Secret (default: none)."),
    ] = None,
    name_prefix: Annotated[
        str, typer.Option("--name-prefix", help="Prefix of the Secrets' names (the manifests use tanklab).")
    ] = "tanklab",
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Write one file per Secret and a kustomization.yaml into DIR."),
    ] = None,
) -> None:
    """Render the Secrets of deploy/kubernetes/ from a home's PKI and users (base64, never a ConfigMap)."""
    from tankctl.k8s import K8sError, read_home, render, secret_manifests
    from tanklab_io.home import SecurityHome
    from tanklab_io.pki import write_file
    from tanklab_io.users import default_home

    try:
        secrets = read_home(SecurityHome(home or default_home()))
        manifests = secret_manifests(secrets, namespace=namespace, prefix=name_prefix)
        if output is not None:
            if output.exists() and not output.is_dir():
                raise K8sError(f"--output {output}: not a directory")
            output.mkdir(mode=0o700, parents=True, exist_ok=True)
            names = []
            for m in manifests:
                name = f"{m['metadata']['name']}.yaml"
                write_file(output / name, render([m]).encode(), 0o600)
                names.append(name)
            listing = "".join(f"  - {n}\n" for n in names)
            kustomization = (
                "# Rendered by `tankctl k8s secrets`: the Secrets of deploy/kubernetes/ (kubectl apply -k).\n"
                "apiVersion: kustomize.config.k8s.io/v1beta1\nkind: Kustomization\n"
                f"resources:\n{listing}"
            )
            write_file(output / "kustomization.yaml", kustomization.encode(), 0o600)
            for n in [*names, "kustomization.yaml"]:
                typer.echo(str(output / n))
        else:
            typer.echo(render(manifests), nl=False)
    except K8sError as e:
        typer.echo(f"tankctl: k8s secrets: {e}", err=True)
        raise typer.Exit(2) from None
    except OSError as e:
        typer.echo(f"tankctl: k8s secrets: {e.filename or output}: {e.strerror or e}", err=True)
        raise typer.Exit(2) from None
    for key in secrets.extra:
        typer.echo(
            f"tankctl: k8s secrets: note: {key} is in Secret {name_prefix}-pki but no manifest projects "
            "it; add it to the pods' `home` volumes (docs/kubernetes.md)",
            err=True,
        )
