"""Site configuration: the plant, the PLC program, the supervisor and the endpoints.

One YAML file describes one site. Every model has ``extra="forbid"`` (a misspelt key is an
error, not a silently ignored default), every field is documented where it is declared, and
units are in the field names (``_m``, ``_m2``, ``_m3_s``, ``_s``) or descriptions.

Plant physics in the file is physical: tanks with a cross-section, orifices with a discharge
coefficient and an area, so that every flow is Torricelli's

    q = mu * a * opening * sign(h_up - h_down) * sqrt(2 g |h_up - h_down|)     [m^3/s]

Pump commands are in the pump's own unit: a flow [m^3/s], a speed [rpm] or a fraction [1],
mapped to flow by an affine law with a dead zone, ``Q = max(0, slope * cmd + offset)``.

:func:`load_site` reads and validates a file; every failure is a :class:`ConfigError` whose
message is one line naming the file, the field and the rule.

The package keeps one module per section: :mod:`~tanklab.config.base` (the base model and value
types), :mod:`~tanklab.config.plant`, :mod:`~tanklab.config.plc`, :mod:`~tanklab.config.supervisor`,
:mod:`~tanklab.config.site` (the whole site and its cross-checks) and :mod:`~tanklab.config.load`
(YAML, environment, schema). Import from ``tanklab.config``: every name is re-exported here.
"""

from tanklab.config.base import (
    GRAVITY_M_S2,
    LOOP_NAME,
    PUMP_NAME,
    TANK_NAME,
    TRANSMITTER_NAME,
    VALVE_NAME,
    Finite,
    Fraction,
    Model,
    NonNegFloat,
    PositiveFloat,
    numeric_key,
)
from tanklab.config.historian import HistorianConfig, RetentionConfig
from tanklab.config.load import (
    ENV_ENDPOINT_VARS,
    apply_env_overrides,
    default_config_path,
    format_validation_error,
    load_model,
    load_site,
    parse_endpoint_url,
    read_yaml,
    sibling_file,
    site_from_mapping,
    site_schema,
)
from tanklab.config.plant import (
    OperatingPoint,
    PlantConfig,
    PlantWatchdog,
    PumpSpec,
    SwitchSpec,
    TankSpec,
    TransmitterSpec,
    ValveSpec,
)
from tanklab.config.plc import (
    GainBox,
    InterlockSpec,
    LoopSpec,
    MracSpec,
    NlpiSpec,
    PidGainsSpec,
    PlcConfig,
    PlcWatchdog,
)
from tanklab.config.site import (
    Endpoint,
    Endpoints,
    SiteConfig,
    StackConfig,
)
from tanklab.config.supervisor import (
    AdaptationSpec,
    ControllerSpec,
    MpcSpec,
    SupervisorConfig,
)
from tanklab.errors import ConfigError

__all__ = [
    "ENV_ENDPOINT_VARS",
    "GRAVITY_M_S2",
    "LOOP_NAME",
    "PUMP_NAME",
    "TANK_NAME",
    "TRANSMITTER_NAME",
    "VALVE_NAME",
    "AdaptationSpec",
    "ConfigError",
    "ControllerSpec",
    "Endpoint",
    "Endpoints",
    "Finite",
    "Fraction",
    "GainBox",
    "HistorianConfig",
    "InterlockSpec",
    "LoopSpec",
    "Model",
    "MpcSpec",
    "MracSpec",
    "NlpiSpec",
    "NonNegFloat",
    "OperatingPoint",
    "PidGainsSpec",
    "PlantConfig",
    "PlantWatchdog",
    "PlcConfig",
    "PlcWatchdog",
    "PositiveFloat",
    "PumpSpec",
    "RetentionConfig",
    "SiteConfig",
    "StackConfig",
    "SupervisorConfig",
    "SwitchSpec",
    "TankSpec",
    "TransmitterSpec",
    "ValveSpec",
    "apply_env_overrides",
    "default_config_path",
    "format_validation_error",
    "load_model",
    "load_site",
    "numeric_key",
    "parse_endpoint_url",
    "read_yaml",
    "sibling_file",
    "site_from_mapping",
    "site_schema",
]
