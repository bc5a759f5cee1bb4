"""Assets: one reader per mesh format into one mesh/material model, the built-in library, content-hashed caches."""
