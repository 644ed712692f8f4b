"""The size / error / run-time report (``bvae bench report``): operating points, evaluation, outputs."""
