"""The algorithm layer: methods that compute a separated solution (the tensor-train time march).
"""
