"""Surface products: rocks, landing hazards, site choice and hillshade."""
