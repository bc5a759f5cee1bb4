"""The data every layer shares: the backend-neutral scene description (IR), job records, frames and units, colour, the lens model."""
