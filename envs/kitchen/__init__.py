"""FrankaKitchen (placeholder until the env lands)."""
