"""Named choices of the simulated world, importable without JAX: manoeuvre families, turbulence levels.

The configuration and the scenario-column registry (:mod:`mcfdd.columns`) name them; the modules
that simulate them (:mod:`mcfdd.plant.manoeuvres`, :mod:`mcfdd.plant.turbulence`) use them.
"""

MANOEUVRE_KINDS = ("quiet", "doublet", "bank_to_bank", "roll_protection", "sideslip",
                   "ol_step", "ol_doublet", "ol_sweep", "ol_multisine",
                   "level_flight", "pitch_doublet", "pedal_doublet", "nose_up", "nose_down", "fpa_change",
                   "heading_change", "speed_change", "coordinated_turn")  # the family code is the index
OPEN_LOOP_KINDS = tuple(k for k in MANOEUVRE_KINDS if k.startswith("ol_"))  # drive the actuator command directly
FULL_AIRCRAFT = ("pitch_doublet", "pedal_doublet", "nose_up", "nose_down", "fpa_change", "heading_change",
                 "speed_change", "coordinated_turn")  # families that only the rcam aircraft can fly
# the traced level of each (turbulence.py)
TURBULENCE_LEVELS = {"none": 0.0, "light": 1.0, "moderate": 2.0, "severe": 3.0}
