"""The measuring chain's sensors: their noise (:mod:`.noise`), the noise of an averaged reading
estimated from correlated samples (:mod:`.noise_estimate`) and their response and coloured noise
(:mod:`.dynamics`). Pure numpy."""
