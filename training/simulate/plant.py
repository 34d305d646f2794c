"""Parameters of the simulated greenhouse, and the two presets.

- ``prototype``: the 0.68 m² floor, 0.76 m³ gable-shaped wooden nursery covered by 0.2 mm
  polyethylene in M'ziraa, Biskra (thesis §II.2.1, table 2). No vents under control: two small
  fixed gaps plus leakage. Seedling trays (3 × 45 × 20 cm of wet soil) on a wooden floor standing on
  the ground; no soil sensor.
- ``almeria``: the 877 m² (37.80 × 23.20 m) Almería-type greenhouse of Las Palmerillas (thesis
  §II.3.1): polyethylene cover, five roof flaps 8.36 × 0.73 m, two side vents 32.75 × 1.90 m
  with insect screens, tomato crop in coir bags on sand-mulched soil, mean height ~3.5 m.

Values not printed in the thesis are typical literature values (cover optics of PE films: Papadakis
et al. 2000, Biosyst. Eng. 77; screens: Muñoz et al. 1999, J. Agric. Eng. Res. 73; soil
properties: Campbell & Norman 1998) and are marked "assumed" below.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from training.simulate.control import GrowerVents, VentController


@dataclass(frozen=True)
class Plant:
    """A simulated greenhouse. All areas [m2], volumes [m3], capacities per m2 of floor."""

    name: str
    floor_area: float  # A_f [m2]
    volume: float  # V [m3]
    cover_area: float  # A_c, all cover surfaces [m2]
    # Cover optics and storage.
    tau_sw: float  # solar transmission of the clean cover [-]
    sun_ratio: float  # radiation intercepted by the house / (I_glob A_f) [-]: >1 for small tall
    # houses whose walls catch the low sun (a 0.8 m high box casts a shadow 2.6 × its floor at
    # 32° sun elevation); 1 for large houses
    alpha_sw: float  # solar absorptance of the cover [-]
    tau_lw: float  # thermal (long-wave) transmittance of the film [-]
    eps_cover: float  # thermal emissivity of the film [-]
    cover_capacity: float  # heat capacity per m2 of cover [J m-2 K-1]
    sky_view: float  # view factor cover -> sky [-] (rest sees surroundings at t_out)
    # Convection coefficients h = a |dT|^(1/3) + b [W m-2 K-1]; outside h = a + b u.
    h_in_a: float
    h_in_b: float
    h_out_a: float
    h_out_b: float
    # Air node and the fast mass lumped with it (structure, crop, pots).
    fast_capacity: float  # [J m-2 K-1] of floor, on top of rho c_p V / A_f
    f_sw_air: float  # share of the transmitted solar radiation absorbed by the fast mass [-]
    # Floor/soil surface and deep layer.
    floor_capacity: float  # [J m-2 K-1]
    floor_alpha_sw: float  # solar absorptance of the floor [-]
    eps_floor: float  # thermal emissivity of floor and crop [-]
    h_floor_up: float  # a in h = a |dT|^(1/3) + 0.3 when floor warmer than air [W m-2 K-4/3]
    h_floor_down: float  # same when the floor is colder (stable layer)
    k_floor_deep: float  # conductance floor -> deep layer [W m-2 K-1]
    deep_capacity: float  # [J m-2 K-1]
    k_deep_ground: float  # conductance deep layer -> ground boundary [W m-2 K-1]
    ground_offset: float  # ground boundary = mean t_out of the run + this [K]
    # Crop (logistic LAI) and transpiration (Stanghellini 1987 big-leaf).
    lai_start: float  # [m2 m-2] at the start of the run
    lai_max: float  # [m2 m-2]
    lai_rate: float  # logistic growth rate [d-1]
    k_ext: float  # short-wave extinction coefficient of the canopy [-]
    alpha_crop: float  # short-wave absorptance of intercepted radiation [-]
    r_b: float  # boundary-layer resistance of leaves [s m-1]
    r_s_min: float  # minimum stomatal resistance [s m-1]
    # Ventilation (Kittas et al. 1997) and leakage.
    roof_n: int  # number of roof flaps [-]
    roof_length: float  # [m]
    roof_width: float  # [m]
    roof_max_angle: float  # flap angle at 100 % [deg]
    side_n: int
    side_length: float  # [m]
    side_height: float  # [m]
    vent_height: float  # vertical distance between side and roof vent centres [m]
    cd: float  # discharge coefficient [-]
    cw: float  # wind pressure coefficient [-]
    screen_factor: float  # factor on Cd for insect screens [-]
    fixed_roof_area: float  # permanent gap at the ridge [m2]
    fixed_side_area: float  # permanent gap low on the walls [m2]
    leak_ach: float  # leakage at no wind [h-1]
    leak_ach_wind: float  # extra leakage per m s-1 of wind [h-1 (m s-1)-1]
    controller: VentController | GrowerVents | None = None
    measured: tuple[str, ...] = ()

    @property
    def height(self) -> float:
        """Mean height V / A_f [m]."""
        return self.volume / self.floor_area

    def to_dict(self) -> dict:
        """Plain dict for the truth JSON."""
        out = asdict(self)
        out["measured"] = list(self.measured)
        return out

    def with_(self, **changes) -> Plant:
        """A copy with some parameters changed (tests, what-if runs)."""
        return replace(self, **changes)


KIT_COLUMNS = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind", "rain")
PRO_COLUMNS = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind", "i_in", "t_soil",
               "vent_roof", "vent_side", "lai")

PROTOTYPE = Plant(
    name="prototype",
    floor_area=0.68, volume=0.76,  # thesis table 2
    cover_area=3.9,  # gable box 0.85 × 0.80 m, 0.8 m walls, 0.4 m ridge (assumed)
    tau_sw=0.82, alpha_sw=0.08, tau_lw=0.55, eps_cover=0.40,  # new 0.2 mm PE (assumed)
    sun_ratio=1.3,  # day mean, between low winter sun and high summer sun (assumed)
    cover_capacity=920.0 * 2300.0 * 0.2e-3,  # rho c d of 0.2 mm PE
    sky_view=0.6,  # walls see half sky, half ground
    h_in_a=1.86, h_in_b=0.5, h_out_a=2.8, h_out_b=3.0,  # Papadakis 1992; Watmuff et al. 1977
    fast_capacity=2500.0,  # wooden frame (assumed)
    f_sw_air=0.25,  # sunlit frame and tray sides heat the air directly
    floor_capacity=57e3,  # 2 cm wood floor + 13.5 kg of wet soil in trays, per 0.68 m2
    floor_alpha_sw=0.75, eps_floor=0.95,
    h_floor_up=3.0, h_floor_down=1.0,  # seedlings and tray rims roughly double the area
    k_floor_deep=5.0,  # 2 cm wood board + contact (assumed)
    deep_capacity=2.0e5,  # 10 cm of ground below the box
    k_deep_ground=2.0, ground_offset=0.0,
    lai_start=0.3, lai_max=1.2, lai_rate=0.08, k_ext=0.7, alpha_crop=0.85,
    r_b=200.0, r_s_min=82.0,
    roof_n=0, roof_length=0.0, roof_width=0.0, roof_max_angle=0.0,
    side_n=0, side_length=0.0, side_height=0.0,
    vent_height=0.6, cd=0.65, cw=0.1, screen_factor=1.0,
    fixed_roof_area=0.002, fixed_side_area=0.003,
    leak_ach=1.5, leak_ach_wind=0.6,
    controller=None,
    measured=KIT_COLUMNS,
)

ALMERIA = Plant(
    name="almeria",
    floor_area=877.0, volume=877.0 * 3.5,  # thesis §II.3.1
    cover_area=1290.0,  # roof ~920 m2 + walls 122 m × 3 m
    tau_sw=0.65, alpha_sw=0.10, tau_lw=0.25, eps_cover=0.65,  # dusty thermal PE (assumed)
    sun_ratio=1.0,
    cover_capacity=920.0 * 2300.0 * 0.2e-3,
    sky_view=0.85,
    h_in_a=1.86, h_in_b=0.5, h_out_a=2.8, h_out_b=3.0,
    fast_capacity=6000.0,  # steel frame, crop, coir bags (assumed)
    f_sw_air=0.03,
    floor_capacity=8.0e4,  # 5 cm sand mulch, rho c = 1.6e6 J m-3 K-1
    floor_alpha_sw=0.7, eps_floor=0.95,
    h_floor_up=1.7, h_floor_down=1.0,
    k_floor_deep=6.7,  # k = 1 W m-1 K-1 over 0.15 m
    deep_capacity=6.0e5,  # 0.3 m of soil, rho c = 2e6 J m-3 K-1
    k_deep_ground=1.7, ground_offset=3.0,
    lai_start=1.5, lai_max=3.5, lai_rate=0.05, k_ext=0.7, alpha_crop=0.85,  # tomato
    r_b=200.0, r_s_min=82.0,
    roof_n=5, roof_length=8.36, roof_width=0.73, roof_max_angle=45.0,  # thesis §II.3.1
    side_n=2, side_length=32.75, side_height=1.90,
    vent_height=2.8, cd=0.65, cw=0.1, screen_factor=0.5,
    fixed_roof_area=0.0, fixed_side_area=0.0,
    leak_ach=0.8, leak_ach_wind=0.3,
    controller=VentController(),
    measured=PRO_COLUMNS,
)

PRESETS: dict[str, Plant] = {"prototype": PROTOTYPE, "almeria": ALMERIA}


def get_plant(plant: str | Plant) -> Plant:
    """A preset by name, or the given :class:`Plant` unchanged."""
    if isinstance(plant, Plant):
        return plant
    try:
        return PRESETS[plant]
    except KeyError:
        raise ValueError(f"unknown plant {plant!r}; presets: {', '.join(PRESETS)}") from None
