"""The tensor layer: separated (CP) tensors and operators, tensor trains; numpy only.
"""
