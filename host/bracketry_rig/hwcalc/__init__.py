"""Hardware calculators: power budget and battery runtime from hw/bom.csv, GigE Vision bandwidth, wiring checks."""
