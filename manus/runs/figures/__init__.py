"""Every figure the `manus` command draws, one module per subject: a builder (`draw_*`) returns a
`matplotlib.figure.Figure` (no pyplot, no backend chosen: a notebook shows it inline), and a file
function writes it into `--out`; `common` holds the style, the layout, the units and saving."""
