module terrad.example/drive

go 1.19
