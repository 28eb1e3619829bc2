"""Research tools on top of scoring (paper §4.3-4.5, appendix C): synthetic scenes (``synth``),
perturbations (``perturb``) and sensitivity studies (``study``), corpus tables (``compare``),
per-pair diagnostics (``diagnostics``), figures (``plot``, needs matplotlib), the fit of the
shipped ``sgc-spec-2026`` calibration (``spec_calibration``) and how closely two scorings of the
same clips agree (``agreement``: the engines, or one engine under two seeds); the validation
protocol's estimator errors (``noise``), its FIT and TEST splits (``protocol``), and tracks against
a clip's own geometry (``ground_truth``).
"""
