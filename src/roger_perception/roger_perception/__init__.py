"""LoG visual buffer, regions of interest, features (eqs. 1-5) and pre-attentive activation."""
