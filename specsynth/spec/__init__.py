"""The dataset spec: pydantic models (the single source of truth), YAML loading with located errors."""
