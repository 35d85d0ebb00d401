"""Choosing a size: the one home of the product's size logic, called by `tryon size`,
`tryon drape` and `tryon serve`.

- `chart`: the size a body's girths point to on the size chart (before any drape).
- `judge`: the fit numbers of one size's drape (ease, strain, pressure per region) and
  whether it fits; the recommendation among several sizes, with its reasons.
- `recommend`: every size draped on a person (predicted, refined or simulated) and judged.
- `quick`: the service's first answer: every size predicted and judged in a fraction of a
  second, then only the sizes that decide refined.
- `outputs`: `size.json` and the picture of every size's strain.
"""
